"""Rig calibration from checkerboard images, as Morimoto & Sketch did (section II, eq. 1).

placeholder: being written
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoardSpec:
    cols: int
    rows: int
    square_mm: float

    def object_points(self) -> np.ndarray:
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([c.ravel() * self.square_mm, r.ravel() * self.square_mm, np.zeros(c.size)], 1)
