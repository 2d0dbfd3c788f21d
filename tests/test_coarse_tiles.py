"""The coarse foreground computed tile by tile from the robot's base (recon._kernels.coarse_foreground_tiles_nb)
is the whole image's in every region that meets the base's window."""
from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from recon._kernels import coarse_foreground_nb, coarse_foreground_tiles_nb

FACTOR, LO, HI, REACH, K = 4, 1, 2, 2, 2


def _scene(seed: int):
    """A random coarse background model and a frame with strokes brighter and darker than it (many of them
    crossing tile borders, some touching each other only diagonally)."""
    rng = np.random.default_rng(seed)
    hc, wc = (int(v) for v in rng.integers(12, 48, 2))
    mean_c = rng.uniform(80, 140, (hc, wc)).astype(np.float32)
    basis_c = rng.normal(0, 3, (K, hc, wc)).astype(np.float32)
    coeff = np.concatenate([[1.0], rng.normal(0, 1, K)])
    bg = mean_c + np.tensordot(coeff[1:], basis_c, axes=1)
    stack = np.repeat(np.concatenate([mean_c[..., None], np.moveaxis(basis_c, 0, -1)], axis=-1)[:, :, None, :], 4, axis=2)
    thr_c = rng.uniform(6, 14, (hc, wc)).astype(np.float32)
    frame = cv2.resize(bg, (wc * FACTOR, hc * FACTOR), interpolation=cv2.INTER_NEAREST) + rng.normal(0, 2, (hc * FACTOR, wc * FACTOR))
    for _ in range(int(rng.integers(1, 12))):
        p0, p1 = rng.integers(0, [wc * FACTOR, hc * FACTOR], (2, 2))
        cv2.line(frame, tuple(int(v) for v in p0), tuple(int(v) for v in p1), float(rng.choice([-40.0, 40.0])) + 110.0,
                 int(rng.integers(1, 9)))
    frame = np.clip(np.rint(frame), 0, 255).astype(np.uint8)
    return frame, mean_c, basis_c, np.ascontiguousarray(stack, np.float32), thr_c, coeff


@given(seed=st.integers(0, 100_000), tile=st.sampled_from([3, 5, 8, 16]), box=st.tuples(*[st.floats(0, 1)] * 4))
def test_tiles_give_the_whole_images_mask_in_every_region_meeting_the_seed_box(seed, tile, box):
    frame, mean_c, basis_c, stack, thr_c, coeff = _scene(seed)
    hc, wc = mean_c.shape
    args = (frame, FACTOR, LO, HI)
    consts = (mean_c, basis_c, stack, thr_c, coeff, REACH)
    full, _ = coarse_foreground_nb(*args, 0, 0, wc, hc, *consts)
    x0, x1 = sorted(int(v * (wc - 1)) for v in box[:2])
    y0, y1 = sorted(int(v * (hc - 1)) for v in box[2:])
    seed_box = np.array([x0, y0, x1 + 1, y1 + 1], np.int64)
    tiled, _, n_tiles = coarse_foreground_tiles_nb(*args, *consts, tile, seed_box)
    # Where a tile was computed the mask is the whole image's; elsewhere it is empty.
    assert np.all((tiled == full) | (tiled == 0))
    n_lab, lab = cv2.connectedComponents(full, connectivity=8)
    meets = np.unique(lab[y0:y1 + 1, x0:x1 + 1])
    region = np.isin(lab, meets[meets > 0])
    assert np.array_equal(tiled[region], full[region])
    # The seed box's tiles are always computed, and nothing is computed twice.
    n_all = -(-hc // tile) * -(-wc // tile)
    assert (y1 // tile - y0 // tile + 1) * (x1 // tile - x0 // tile + 1) <= n_tiles <= n_all


def test_a_region_that_crosses_a_tile_corner_diagonally_is_followed():
    # One coarse pixel a step down the diagonal: from tile (0, 0) the region enters tile (1, 1) only
    # through its corner, touching neither the tile to the right nor the one below.
    hc = wc = 24
    mean_c = np.full((hc, wc), 100.0, np.float32)
    basis_c = np.zeros((K, hc, wc), np.float32)
    stack = np.zeros((hc, wc, 4, K + 1), np.float32)
    stack[..., 0] = 100.0
    frame = np.full((hc * FACTOR, wc * FACTOR), 100, np.uint8)
    for i in range(20):
        frame[i * FACTOR + LO: i * FACTOR + HI + 1, i * FACTOR + LO: i * FACTOR + HI + 1] = 200
    consts = (mean_c, basis_c, stack, np.full((hc, wc), 10.0, np.float32), np.array([1.0, 0.0, 0.0]), REACH)
    tiled, _, n_tiles = coarse_foreground_tiles_nb(frame, FACTOR, LO, HI, *consts, 8, np.array([0, 0, 2, 2], np.int64))
    assert np.array_equal(np.flatnonzero(tiled.ravel()), [i * wc + i for i in range(20)])
    # The diagonal's three tiles and the two beside each corner it crosses (a corner pixel lies on both borders);
    # the two far corners of the 3 x 3 tiles are never computed.
    assert n_tiles == 7
