"""Time the image operations recon/ uses against their scikit-image (and SciPy) counterparts.

Issue 16 asks for scikit-image wherever it is the right tool, and for a measurement wherever
OpenCV, SciPy or a hand-written kernel is kept instead. This prints, for a 1024x768 silhouette
of a bent two-tube robot with specks of noise (the paper rig's image size), the best of
``--repeat`` calls of each implementation, and checks that they agree where recon/ relies on
them agreeing (region areas, distances, dilation, the coarse path's length).

Usage: ``.venv/bin/python scripts/bench_libraries.py [--repeat 30]``. docs/libraries.md quotes
its figures.
"""
from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from scipy import ndimage
from skimage import graph, measure, morphology

from recon._kernels import bfs_path_nb
from recon.centerline import remove_small_regions
from recon.morphology import disk


def robot_mask(height: int = 768, width: int = 1024, seed: int = 0) -> np.ndarray:
    """(H, W) uint8 0/1: a bent outer tube (18 px) and inner tube (10 px), plus 200 specks."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, 400)
    outer = np.c_[100 + 500 * s, 380 + 40 * np.sin(3 * s)]
    inner = np.c_[600 + 300 * s, outer[-1, 1] + 200 * s ** 2]
    m = np.zeros((height, width), np.uint8)
    cv2.polylines(m, [np.round(outer).astype(np.int32)], False, 1, 18)
    cv2.polylines(m, [np.round(inner).astype(np.int32)], False, 1, 10)
    ys, xs = rng.integers(0, height, 200), rng.integers(0, width, 200)
    m[ys, xs] = 1
    return m


def best_ms(fn, repeat: int) -> float:
    """The fastest of ``repeat`` calls of ``fn()`` (ms): the least disturbed by the machine's load."""
    fn()
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return 1e3 * best


def mcp_path(mask: np.ndarray, sy: int, sx: int) -> np.ndarray:
    """skimage's minimal-cost path from (sy, sx) to the farthest pixel of ``mask`` (8-connected, unit cost)."""
    cost = np.where(mask > 0, 1.0, np.inf)
    m = graph.MCP(cost, fully_connected=True)
    d, _ = m.find_costs([(sy, sx)])
    d[~np.isfinite(d)] = -1
    end = np.unravel_index(np.argmax(d), d.shape)
    return np.array(m.traceback(end))


def rows(mask: np.ndarray, repeat: int) -> list:
    """(operation, implementation, ms, agreement note) for each operation measured."""
    out = []
    b = mask.astype(bool)

    def cv_cc():
        return cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)

    def sk_cc():
        lab = measure.label(b, connectivity=2)
        return lab, measure.regionprops(lab)

    n_cv = cv_cc()[0] - 1
    n_sk = len(sk_cc()[1])
    areas_cv = np.sort(cv_cc()[2][1:, cv2.CC_STAT_AREA])
    areas_sk = np.sort([r.area for r in sk_cc()[1]])
    agree = f"{n_cv} vs {n_sk} regions, areas {'equal' if np.array_equal(areas_cv, areas_sk) else 'differ'}"
    out += [("regions + areas/boxes", "cv2.connectedComponentsWithStats (kept)", best_ms(cv_cc, repeat), agree),
            ("", "skimage.measure.label + regionprops", best_ms(sk_cc, repeat), ""),
            ("", "scipy.ndimage.label + find_objects", best_ms(lambda: ndimage.find_objects(ndimage.label(b, np.ones((3, 3)))[0]), repeat), "")]

    keep_ours = remove_small_regions(mask, 50)
    keep_sk = morphology.remove_small_objects(b, max_size=49, connectivity=2)
    out += [("small regions removed", "recon.centerline.remove_small_regions (kept)", best_ms(lambda: remove_small_regions(mask, 50), repeat),
             f"{'equal' if np.array_equal(keep_ours, keep_sk) else 'differ'} to skimage's"),
            ("", "skimage.morphology.remove_small_objects", best_ms(lambda: morphology.remove_small_objects(b, max_size=49, connectivity=2), repeat), "")]

    d_cv = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_5)
    d_sp = ndimage.distance_transform_edt(b)
    out += [("distance to background", "cv2.distanceTransform 5x5 (kept)", best_ms(lambda: cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_5), repeat),
             f"max |diff| to exact {np.abs(d_cv - d_sp).max():.3f} px"),
            ("", "cv2.distanceTransform exact (DIST_MASK_PRECISE)", best_ms(lambda: cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE), repeat), ""),
            ("", "scipy.ndimage.distance_transform_edt", best_ms(lambda: ndimage.distance_transform_edt(b), repeat), ""),
            ("", "skimage.morphology.medial_axis (+distance)", best_ms(lambda: morphology.medial_axis(b, return_distance=True), max(3, repeat // 10)), "")]

    fp = disk(5)
    dil_cv = cv2.dilate(mask, fp)
    dil_sk = morphology.dilation(mask, fp)
    out += [("dilation by a disk of 5 px", "cv2.dilate (kept)", best_ms(lambda: cv2.dilate(mask, fp), repeat),
             f"{'equal' if np.array_equal(dil_cv, dil_sk) else 'differ'} to skimage's with the same footprint"),
            ("", "skimage.morphology.dilation", best_ms(lambda: morphology.dilation(mask, fp), repeat), ""),
            ("", "scipy.ndimage.binary_dilation", best_ms(lambda: ndimage.binary_dilation(b, fp), repeat), "")]

    # The fast method's coarse stage traces the path on the region pooled 2x2 at a 1/4-scale image.
    small = cv2.resize(mask, (mask.shape[1] // 8, mask.shape[0] // 8), interpolation=cv2.INTER_AREA)
    small = (small > 0).astype(np.uint8) & (ndimage.label(small > 0, np.ones((3, 3)))[0] == 1)
    ys, xs = np.nonzero(small)
    k = int(np.argmin(xs))
    p_ours = bfs_path_nb(np.ascontiguousarray(small), int(ys[k]), int(xs[k]))
    p_sk = mcp_path(small, int(ys[k]), int(xs[k]))
    out += [("path to the farthest pixel (coarse)", "recon._kernels.bfs_path_nb (kept)", best_ms(lambda: bfs_path_nb(small, int(ys[k]), int(xs[k])), repeat),
             f"{len(p_ours)} vs {len(p_sk)} path pixels"),
            ("", "skimage.graph.MCP + traceback", best_ms(lambda: mcp_path(small, int(ys[k]), int(xs[k])), repeat), "")]

    out += [("centerline of the silhouette", "skimage.morphology.skeletonize", best_ms(lambda: morphology.skeletonize(b), max(3, repeat // 10)),
             "not the paper's method: see docs/libraries.md"),
            ("", "skimage.morphology.thin", best_ms(lambda: morphology.thin(b), max(3, repeat // 10)), "")]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=30, help="calls per implementation; the best is printed")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    mask = robot_mask()
    print(f"1024x768 mask, {int(mask.sum())} foreground px; best of {args.repeat} calls, one thread for OpenCV")
    print(f"{'operation':<36} {'implementation':<48} {'ms':>8}  agreement")
    for op, impl, ms, note in rows(mask, args.repeat):
        print(f"{op:<36} {impl:<48} {ms:8.3f}  {note}")


if __name__ == "__main__":
    main()
