"""Structuring elements for binary morphology on silhouettes.

One owner of the disk that the silhouette's closing and the centerline's erosions use.

The binary image operations of recon/ (regions and their statistics, distance transforms,
dilation and erosion) run through OpenCV rather than scikit-image or SciPy: on the paper
rig's 1024x768 silhouettes OpenCV is 3-30x faster with the same results
(``scripts/bench_libraries.py``; figures and the choice, operation by operation, in
docs/libraries.md).
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["disk"]


def disk(radius_px: int) -> np.ndarray:
    """A filled disk of ``radius_px`` as a structuring element.

    Parameters
    ----------
    radius_px : int
        Radius in pixels (truncated to an integer); 0 gives a single pixel.

    Returns
    -------
    (2r+1, 2r+1) uint8 array
        OpenCV's ellipse element (1 inside, 0 outside). From radius 2 on it is fuller on
        the rim than ``skimage.morphology.disk`` (at r = 3, rows 2 and 4 reach the edge), so
        the two are not interchangeable without changing the silhouettes and centerlines.
    """
    d = 2 * int(radius_px) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (d, d))
