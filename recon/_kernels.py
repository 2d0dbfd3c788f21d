"""Compiled (numba) per-pixel loops of the fast method: its one production path.

:mod:`recon.subpixel` and :mod:`recon.fast` call these (numba is a
dependency). Each kernel fuses what NumPy does in a dozen array passes into
one loop, which matters because the work per frame is small (~1 % of the
pixels) and NumPy's per-call overhead would dominate. The NumPy versions
survive as test oracles (``tests/fast_oracles.py``; the tests compare each
kernel with its oracle, to rounding).

Pixel coordinates are those of the image frame (OpenCV: (0, 0) is the centre
of the top-left pixel), in full-resolution px unless said otherwise;
differences from the background are in gray levels. ``stack`` is
:attr:`recon.subpixel.ViewModel.stack` ((H*W, k+1) float32, pixel-major
mean and eigenbackgrounds) and ``coeff`` the frame's ``[1, c_1..c_k]``
(:func:`recon.subpixel.frame_coefficients`): the background at pixel ``p``
is ``stack[p] @ coeff``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from . import distortion

# The distortion formula has one owner (recon.distortion); these are its compiled forms.
_distort_nb = njit(cache=True, nogil=True, inline="always")(distortion.distort_xy)
_untilt_nb = njit(cache=True, nogil=True, inline="always")(distortion.untilt_xy)
_undistort_step_nb = njit(cache=True, nogil=True, inline="always")(distortion.undistort_step)

__all__ = ["profile_edges_nb", "profiles_at_seeds_nb", "profile_values_nb", "coarse_foreground_nb", "coarse_foreground_tiles_nb",
           "bfs_path_nb", "traced_path_nb", "rays_nb", "ridge_hits_nb", "near_any_nb", "spline_fit_nb", "spline_basis_nb", "spline_eval_nb", "spline_robust_nb", "frame_coefficients_nb",
           "frame_shift_nb", "tip_along_axis_nb", "project_nb", "running_rank_nb", "median_nb", "max_window_median_nb",
           "best_path_nb"]


@njit(cache=True, nogil=True, inline="always")
def _add_line(d, frame, stack, coeff, cu, cv, ax, half, o, H, W):
    """Add the background difference of the line offset ``o`` along the tube to ``d``; False when outside."""
    L = 2 * half + 1
    k1 = coeff.shape[0]
    if ax:
        r = cv + o
        if r < 0 or r >= H:
            return False
        base = r * W + cu - half
        stride = 1
    else:
        c0 = cu + o
        if c0 < 0 or c0 >= W:
            return False
        base = (cv - half) * W + c0
        stride = W
    # The usual mean and 5 eigenbackgrounds as a constant count, which the compiler unrolls: ~10 % of the
    # profiles' kernel, the same sums in the same order.
    if k1 == 6:
        _line_difference(d, frame, stack, coeff, base, stride, L, 6)
    else:
        _line_difference(d, frame, stack, coeff, base, stride, L, k1)
    return True


@njit(cache=True, nogil=True, inline="always")
def _line_difference(d, frame, stack, coeff, base, stride, L, k1):
    """Add ``frame - background`` (gray levels) at the ``L`` flat pixel indices ``base + j stride`` to ``d[j]``,
    the background summed over the ``k1`` columns of ``stack`` in order."""
    for j in range(L):
        p = base + j * stride
        bg = 0.0
        for c in range(k1):
            bg += stack[p, c] * coeff[c]
        d[j] += frame.flat[p] - bg


@njit(cache=True, nogil=True, inline="always")
def _edges_1d(d, threshold, out):
    """Sub-pixel edges of one profile ``d`` into ``out`` = (e1, e2, weaker rim); False when there are none."""
    L = d.shape[0]
    i1 = -1
    i2 = -1
    for j in range(L):
        if abs(d[j]) > threshold:
            if i1 < 0:
                i1 = j
            i2 = j
    if i1 < 2 or i2 > L - 3 or i2 - i1 < 1:
        return False
    s1 = 1.0 if d[i1] > 0 else -1.0
    s2 = 1.0 if d[i2] > 0 else -1.0
    r1 = -1e30
    r2 = -1e30
    for j in range(3):
        if d[i1 + j] * s1 > r1:
            r1 = d[i1 + j] * s1
        if d[i2 - j] * s2 > r2:
            r2 = d[i2 - j] * s2
    if r1 <= threshold or r2 <= threshold:
        return False
    w1 = 0.0
    w2 = 0.0
    for j in range(-1, 2):
        a = d[i1 + j] * s1 / r1
        w1 += 0.0 if a < 0.0 else (1.0 if a > 1.0 else a)
        b = d[i2 - j] * s2 / r2
        w2 += 0.0 if b < 0.0 else (1.0 if b > 1.0 else b)
    out[0] = i1 + 1.5 - w1
    out[1] = i2 - 1.5 + w2
    out[2] = min(r1, r2)
    return True


@njit(cache=True, nogil=True)
def profile_edges_nb(frame, stack, coeff, cu, cv, axis, half, threshold, nav, threshold1, strong):
    """Cut the profiles and find their sub-pixel edges (see :func:`recon.subpixel.edges_from_profiles`).

    Profile ``i`` is the mean of ``2 nav[i] + 1`` parallel lines, offset by
    ``-nav[i]..nav[i]`` px along the tube (rows for a row profile); lines outside
    the image are left out. The middle line is tried alone first (threshold
    ``threshold1``): where both its rims exceed ``strong`` the other lines
    are not cut, nor where none of its samples exceeds ``threshold`` (no
    tube there); ``strong`` = inf: always average.

    Parameters
    ----------
    frame : (H, W) uint8 array
        The frame (gray levels).
    stack : (H*W, k+1) float32 array
        Mean background and eigenbackgrounds, pixel-major.
    coeff : (k+1,) float32 array
        The frame's background coefficients.
    cu, cv : (n,) int64 arrays
        Window centres (px), kept inside the image by the caller.
    axis : (n,) int8 array
        1: the profile runs along u (a row), 0: along v (a column).
    half : int
        Half-length of the profiles (px).
    threshold, threshold1 : float
        Edge thresholds of an averaged profile and of the middle line (gray levels).
    nav : (n,) int64 array
        Lines averaged on each side of the middle one.
    strong : float
        Rim contrast (gray levels) above which the middle line's edges are taken.

    Returns
    -------
    e1, e2 : (n,) float64 arrays
        Edge positions (samples from the window's first sample).
    ok : (n,) bool array
        Both edges found.
    lines : (n,) int64 array
        Lines averaged.
    """
    H, W = frame.shape
    n = cu.shape[0]
    L = 2 * half + 1
    e1 = np.zeros(n)
    e2 = np.zeros(n)
    ok = np.zeros(n, np.bool_)
    used = np.zeros(n, np.int64)
    d = np.empty(L)
    out = np.empty(3)
    for i in range(n):
        for j in range(L):
            d[j] = 0.0
        m = 1 if _add_line(d, frame, stack, coeff, cu[i], cv[i], axis[i], half, 0, H, W) else 0
        if nav[i] > 0 and m == 1 and np.isfinite(strong):
            if _edges_1d(d, threshold1, out) and out[2] >= strong:
                e1[i] = out[0]
                e2[i] = out[1]
                ok[i] = True
                used[i] = 1
                continue
            beyond = False
            for j in range(L):
                if abs(d[j]) > threshold:
                    beyond = True
                    break
            if not beyond:
                used[i] = 1
                continue  # not one sample of the middle line beyond the mean's threshold: no tube here
        for o in range(-nav[i], nav[i] + 1):
            if o != 0 and _add_line(d, frame, stack, coeff, cu[i], cv[i], axis[i], half, o, H, W):
                m += 1
        if m == 0:
            continue
        for j in range(L):
            d[j] /= m
        used[i] = m
        if _edges_1d(d, threshold, out):
            e1[i] = out[0]
            e2[i] = out[1]
            ok[i] = True
    return e1, e2, ok, used


@njit(cache=True, nogil=True)
def coarse_foreground_nb(frame, factor, lo, hi, rx0, ry0, rx1, ry1, mean_c, basis_c, coarse_stack, thr_c, coeff, reach):
    """Coarse foreground mask of the ROI (see :func:`recon.subpixel.coarse_path`).

    A coarse pixel is foreground when ``|2x2 average - background|`` exceeds
    its threshold, or, within ``reach`` coarse pixels of such a pixel, when the
    mean absolute difference of its 2x2 pixels does
    (:func:`recon.subpixel.coarse_abs_difference`).

    Parameters
    ----------
    frame : (H, W) uint8 array
        The frame (gray levels).
    factor : int
        Full-resolution px per coarse px.
    lo, hi : int
        Offsets (px) of the central 2x2 pixels within a ``factor`` block.
    rx0, ry0, rx1, ry1 : int
        The ROI (coarse px, image frame).
    mean_c : (Hc, Wc) float32 array
        Coarse mean background.
    basis_c : (k, Hc, Wc) float32 array
        Coarse eigenbackgrounds.
    coarse_stack : (Hc, Wc, 4, k+1) float32 array
        ``stack`` rows at each coarse pixel's central 2x2 pixels.
    thr_c : (Hc, Wc) float32 array
        Threshold per coarse pixel (gray levels).
    coeff : (k+1,) float64 array
        The frame's background coefficients.
    reach : int
        Coarse px around the first pass's foreground where the second is tried.

    Returns
    -------
    mask : (ry1-ry0, rx1-rx0) uint8 array
        1 = foreground.
    best : float
        The largest excess over the threshold (gray levels; <= 0: no foreground).
    """
    k = basis_c.shape[0]
    hr = ry1 - ry0
    wr = rx1 - rx0
    mask = np.zeros((hr, wr), np.uint8)
    best = -1e30
    r = np.empty(wr)
    fg_row = np.zeros(hr, np.bool_)
    # Row by row, one array at a time: loops the compiler vectorizes (about 1.3x faster on the wide suite's
    # frames, warm, than a loop over pixels that reads all k + 2 planes at each), the same arithmetic in the
    # same order.
    for y in range(hr):
        yc = ry0 + y
        f0 = frame[yc * factor + lo]
        f1 = frame[yc * factor + hi]
        m = mean_c[yc]
        for x in range(wr):
            fx0 = (rx0 + x) * factor + lo
            fx1 = (rx0 + x) * factor + hi
            r[x] = 0.25 * (np.float64(f0[fx0]) + f0[fx1] + f1[fx0] + f1[fx1]) - m[rx0 + x]
        for j in range(k):
            c = coeff[j + 1]
            b = basis_c[j, yc]
            for x in range(wr):
                r[x] -= c * b[rx0 + x]
        t = thr_c[yc]
        mrow = mask[y]
        n_fg = 0
        for x in range(wr):
            e = abs(r[x]) - t[rx0 + x]
            mrow[x] = e > 0.0
            n_fg += mrow[x]
            best = max(best, e)
        fg_row[y] = n_fg > 0
    best = _abs_pass(frame, factor, lo, hi, rx0, ry0, mask, fg_row, coarse_stack, thr_c, coeff, reach, best)
    return mask, best


@njit(cache=True, nogil=True)
def coarse_foreground_tiles_nb(frame, factor, lo, hi, mean_c, basis_c, coarse_stack, thr_c, coeff, reach, tile, seed_box):
    """:func:`coarse_foreground_nb` of the whole image, computed only in the tiles a foreground region can reach
    from ``seed_box``.

    The coarse image is cut into ``tile`` x ``tile`` tiles. Those meeting ``seed_box`` = (x0, y0, x1, y1)
    (coarse px) are computed first; a tile's neighbour (8-connected) follows wherever the tile has
    foreground on the border they share. Each tile is computed with a margin of ``reach`` px, so its
    second pass sees every first-pass pixel it depends on: the mask in the computed tiles is the whole
    image's, and every foreground region that meets ``seed_box`` lies entirely in computed tiles.

    Parameters
    ----------
    frame, factor, lo, hi, mean_c, basis_c, coarse_stack, thr_c, coeff, reach
        As :func:`coarse_foreground_nb` (the whole image: no region of interest).
    tile : int
        Coarse px a side of a tile.
    seed_box : (4,) int64 array
        ``(x0, y0, x1, y1)`` coarse px (x1, y1 exclusive): where the regions of interest start.

    Returns
    -------
    mask : (Hc, Wc) uint8 array
        1 = foreground; 0 also in the tiles not computed.
    best : float
        The largest excess over the threshold in the computed tiles and their margins (gray levels).
    n_tiles : int
        Tiles computed.
    """
    hc, wc = mean_c.shape
    nty = (hc + tile - 1) // tile
    ntx = (wc + tile - 1) // tile
    mask = np.zeros((hc, wc), np.uint8)
    state = np.zeros((nty, ntx), np.uint8)  # 1 queued, 2 computed
    queue = np.empty(nty * ntx, np.int64)
    n_q = 0
    for ty in range(max(0, seed_box[1] // tile), min(nty, (seed_box[3] - 1) // tile + 1)):
        for tx in range(max(0, seed_box[0] // tile), min(ntx, (seed_box[2] - 1) // tile + 1)):
            state[ty, tx] = 1
            queue[n_q] = ty * ntx + tx
            n_q += 1
    best = -1e30
    head = 0
    while head < n_q:
        ty, tx = divmod(queue[head], ntx)
        head += 1
        state[ty, tx] = 2
        y0, x0 = ty * tile, tx * tile
        y1, x1 = min(hc, y0 + tile), min(wc, x0 + tile)
        my0, mx0 = max(0, y0 - reach), max(0, x0 - reach)
        my1, mx1 = min(hc, y1 + reach), min(wc, x1 + reach)
        m, b = coarse_foreground_nb(frame, factor, lo, hi, mx0, my0, mx1, my1, mean_c, basis_c, coarse_stack, thr_c,
                                    coeff, reach)
        best = max(best, b)
        mask[y0:y1, x0:x1] = m[y0 - my0:y1 - my0, x0 - mx0:x1 - mx0]
        t = mask[y0:y1, x0:x1]
        h, w = y1 - y0, x1 - x0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                ny, nx = ty + dy, tx + dx
                if (dy == 0 and dx == 0) or ny < 0 or ny >= nty or nx < 0 or nx >= ntx or state[ny, nx] != 0:
                    continue
                # Foreground on the border shared with that neighbour (a corner pixel for a diagonal one).
                ra, rb = (0, 1) if dy < 0 else ((h - 1, h) if dy > 0 else (0, h))
                ca, cb = (0, 1) if dx < 0 else ((w - 1, w) if dx > 0 else (0, w))
                hit = False
                for yy in range(ra, rb):
                    for xx in range(ca, cb):
                        if t[yy, xx]:
                            hit = True
                            break
                    if hit:
                        break
                if hit:
                    state[ny, nx] = 1
                    queue[n_q] = ny * ntx + nx
                    n_q += 1
    return mask, best, head


@njit(cache=True, nogil=True)
def _abs_pass(frame, factor, lo, hi, rx0, ry0, mask, fg_row, coarse_stack, thr_c, coeff, reach, best):
    """The second pass of :func:`coarse_foreground_nb`: within ``reach`` coarse px of the first pass's
    foreground (rows ``fg_row``), the 2x2 pixels' mean absolute difference against the threshold. Adds its
    foreground to ``mask`` (in place) and returns the largest excess so far, ``best`` included."""
    hr, wr = mask.shape
    k1 = coarse_stack.shape[3]
    # Only where the first pass found something: a few rows of a mostly empty frame.
    near = np.zeros((hr, wr), np.uint8)
    near_row = np.zeros(hr, np.bool_)
    for y in range(hr):
        if not fg_row[y]:
            continue
        for yy in range(max(0, y - reach), min(hr, y + reach + 1)):
            near_row[yy] = True
        for x in range(wr):
            if mask[y, x]:
                for yy in range(max(0, y - reach), min(hr, y + reach + 1)):
                    for xx in range(max(0, x - reach), min(wr, x + reach + 1)):
                        near[yy, xx] = 1
    for y in range(hr):
        if not near_row[y]:
            continue
        yc = ry0 + y
        for x in range(wr):
            if mask[y, x] or not near[y, x]:
                continue
            xc = rx0 + x
            acc = 0.0
            i = 0
            for fy in (yc * factor + lo, yc * factor + hi):
                for fx in (xc * factor + lo, xc * factor + hi):
                    b = 0.0
                    for j in range(k1):
                        b += coeff[j] * coarse_stack[yc, xc, i, j]
                    acc += abs(np.float64(frame[fy, fx]) - b)
                    i += 1
            e = 0.25 * acc - thr_c[yc, xc]
            if e > 0.0:
                mask[y, x] = 1
            if e > best:
                best = e
    return best


@njit(cache=True, nogil=True)
def bfs_path_nb(mask, sy, sx):
    """Breadth-first path in an 8-connected mask from (sy, sx) to the farthest pixel (ties: farthest in the plane).

    Parameters
    ----------
    mask : (h, w) uint8 array
        The region (non-zero), in its own pixel grid (e.g. coarse px pooled 2x2).
    sy, sx : int
        The start (row, column) of that grid, inside the region.

    Returns
    -------
    (n, 2) int64 array
        ``(y, x)`` of the path's pixels, start first.
    """
    h, w = mask.shape
    pred = np.full(h * w, -2, np.int64)
    dist = np.full(h * w, -1, np.int64)
    queue = np.empty(h * w, np.int64)
    s = sy * w + sx
    pred[s] = -1
    dist[s] = 0
    head = 0
    tail = 1
    queue[0] = s
    while head < tail:
        node = queue[head]
        head += 1
        y = node // w
        x = node - y * w
        for dy in range(-1, 2):
            yy = y + dy
            if yy < 0 or yy >= h:
                continue
            for dx in range(-1, 2):
                xx = x + dx
                if (dy == 0 and dx == 0) or xx < 0 or xx >= w:
                    continue
                m = yy * w + xx
                if mask[yy, xx] and pred[m] == -2:
                    pred[m] = node
                    dist[m] = dist[node] + 1
                    queue[tail] = m
                    tail += 1
    dmax = dist[queue[tail - 1]]
    end = queue[tail - 1]
    best = -1.0
    for q in range(tail):
        node = queue[q]
        if dist[node] == dmax:
            y = node // w
            x = node - y * w
            e = (y - sy) ** 2 + (x - sx) ** 2
            if e > best:
                best = e
                end = node
    n = dist[end] + 1
    path = np.empty((n, 2), np.int64)
    node = end
    for q in range(n - 1, -1, -1):
        path[q, 0] = node // w
        path[q, 1] = node - (node // w) * w
        node = pred[node]
    return path


@njit(cache=True, nogil=True)
def _ahead_region(mask, sx, sy, sw, sh, rx0, ry0, x0p, y0p, x1p, y1p, bx, by, ax0, ax1, margin, ahead):
    """The flood-filled region (``mask == 2``, ``mask`` from ``(rx0, ry0)``) in its rectangle ``(sx, sy, sw, sh)``,
    as a uint8 array of coarse px from ``(x0p, y0p)`` to ``(x1p, y1p)``; with ``ahead``, its pixels more than
    ``margin`` (coarse px) behind the base ``(bx, by)`` along the image axis ``(ax0, ax1)`` dropped, unless
    fewer than two would be left (see :func:`recon.subpixel._traced_path`)."""
    region = np.zeros((y1p - y0p, x1p - x0p), np.uint8)
    for y in range(sh):
        for x in range(sw):
            region[sy - y0p + y, sx - x0p + x] = mask[sy - ry0 + y, sx - rx0 + x] == 2
    if not ahead:
        return region
    h, w = region.shape
    behind = np.zeros((h, w), np.bool_)
    left = 0
    for y in range(h):
        for x in range(w):
            # (x - bx) a + (y - by) b in NumPy's order: the same comparison bit for bit.
            behind[y, x] = (np.float64(x0p + x) - bx) * ax0 + (np.float64(y0p + y) - by) * ax1 < -margin
            left += region[y, x] != 0 and not behind[y, x]
    if left >= 2:
        for y in range(h):
            for x in range(w):
                if behind[y, x]:
                    region[y, x] = 0
    return region


@njit(cache=True, nogil=True)
def traced_path_nb(mask, sx, sy, sw, sh, rx0, ry0, hc, wc, bx, by, ax0, ax1, margin, ahead):
    """:func:`recon.subpixel._traced_path` in one call: the region, pooled 2x2, its pixel nearest the base
    ``(bx, by)`` (coarse px; the first of equals in raster order) and the :func:`bfs_path_nb` from there.

    Parameters
    ----------
    mask : 2-D int array
        The flood fill (``2``: the robot's region), its pixel (0, 0) at coarse px ``(rx0, ry0)``.
    sx, sy, sw, sh : int
        The region's rectangle in the coarse image (px).
    rx0, ry0 : int
        Where ``mask`` starts in the coarse image (px).
    hc, wc : int
        The coarse image's height and width (px).
    bx, by : float
        The robot base in the coarse image (px).
    ax0, ax1, margin : float
        The insertion axis's image direction (unit) and how far behind the base (coarse px) the region is
        kept, where ``ahead``.
    ahead : bool
        Drop the region's pixels more than ``margin`` behind the base (see :func:`_ahead_region`).

    Returns
    -------
    tuple
        ``(path, g, region, x0p, y0p)`` as :func:`recon.subpixel._traced_path` gives it: (n, 2) (y, x) cells
        of the grid pooled ``g`` x ``g``, and the (uint8) region of coarse px from ``(x0p, y0p)``.
    """
    x0p, y0p = sx - (sx & 1), sy - (sy & 1)
    x1p, y1p = min(wc, sx + sw + ((sx + sw) & 1)), min(hc, sy + sh + ((sy + sh) & 1))
    region = _ahead_region(mask, sx, sy, sw, sh, rx0, ry0, x0p, y0p, x1p, y1p, bx, by, ax0, ax1, margin, ahead)
    ph, pw = region.shape[0] // 2, region.shape[1] // 2
    g = 2
    pooled = _pooled(region) if ph and pw else region  # a region one cell thin is left as it is (at g = 2)
    if not np.any(pooled):
        # A degenerate (tiny) region: no pooling.
        g, x0p, y0p = 1, sx, sy
        region = _ahead_region(mask, sx, sy, sw, sh, rx0, ry0, sx, sy, sx + sw, sy + sh, bx, by, ax0, ax1, margin,
                               False)
        pooled = region
    best = np.inf
    ky, kx = -1, -1
    for y in range(pooled.shape[0]):
        for x in range(pooled.shape[1]):
            if pooled[y, x]:
                a = (x + 0.5) * g + x0p - 0.5 - bx
                b = (y + 0.5) * g + y0p - 0.5 - by
                e = a * a + b * b
                if e < best or ky < 0:
                    best, ky, kx = e, y, x
    if ky < 0:
        raise ValueError("attempt to get argmin of an empty sequence")  # as np.argmin on the empty region
    return bfs_path_nb(pooled, ky, kx), g, region, x0p, y0p


@njit(cache=True, nogil=True)
def _pooled(region):
    """``region`` (h, w) uint8 pooled 2x2 (a cell is set where any of its four is), odd last rows and columns left out."""
    ph, pw = region.shape[0] // 2, region.shape[1] // 2
    pooled = np.empty((ph, pw), np.uint8)
    for y in range(ph):
        for x in range(pw):
            pooled[y, x] = (region[2 * y, 2 * x] | region[2 * y + 1, 2 * x] | region[2 * y, 2 * x + 1]
                            | region[2 * y + 1, 2 * x + 1])
    return pooled


@njit(cache=True, nogil=True)
def rays_nb(uv, K, d, m_inv, R, baseline, e1, e2, epipole, iterations):
    """Pixels -> unnormalized world ray directions, epipolar angles and conditioning, in one pass.

    Same as :func:`recon.distortion.undistort_normalized` with at most ``iterations`` fixed-point steps
    + ``R @ [x, y, 1]`` + :meth:`recon.epipolar.EpipolarFrame.phi` + :func:`recon.epipolar.conditioning`
    (tangent by central differences).

    Parameters
    ----------
    uv : (n, 2) float64 array
        Distorted pixels of one camera (image frame, px), in order along a curve.
    K : (3, 3) array
        The camera matrix.
    d : (14,) array
        The distortion coefficients (OpenCV order).
    m_inv : (3, 3) array
        The inverse tilt matrix.
    R : (3, 3) array
        Rotation camera -> world.
    baseline, e1, e2 : (3,) arrays
        The epipolar frame (world): the baseline and the two axes the plane
        angle is measured in.
    epipole : (3,) array
        The other camera's centre in this camera's frame (mm).
    iterations : int
        Most fixed-point steps of the undistortion.

    Returns
    -------
    dirs : (n, 3) float64 array
        Unnormalized ray directions (world frame); NaN where the steps did not settle.
    phi : (n,) float64 array
        Epipolar-plane angles (rad); NaN where the steps did not settle.
    cond : (n,) float64 array
        |sin| of the angle between the curve and the epipolar lines.
    """
    n = uv.shape[0]
    xy = _normalized_nb(uv, K, d, m_inv, iterations)
    dirs = np.empty((n, 3))
    phi = np.empty(n)
    cond = np.empty(n)
    bx, by, bz = baseline[0], baseline[1], baseline[2]
    ex, ey, ez = epipole[0], epipole[1], epipole[2]
    for i in range(n):
        x = xy[i, 0]
        y = xy[i, 1]
        dx = R[0, 0] * x + R[0, 1] * y + R[0, 2]
        dy = R[1, 0] * x + R[1, 1] * y + R[1, 2]
        dz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
        dirs[i, 0] = dx
        dirs[i, 1] = dy
        dirs[i, 2] = dz
        nx = by * dz - bz * dy
        ny = bz * dx - bx * dz
        nz = bx * dy - by * dx
        phi[i] = np.arctan2(nx * e2[0] + ny * e2[1] + nz * e2[2], nx * e1[0] + ny * e1[1] + nz * e1[2])
        a = i - 1 if i > 0 else 0
        b = i + 1 if i < n - 1 else n - 1
        tx = xy[b, 0] - xy[a, 0]
        ty = xy[b, 1] - xy[a, 1]
        tn = np.sqrt(tx * tx + ty * ty) + 1e-300
        lx = ex - x * ez
        ly = ey - y * ez
        ln = np.sqrt(lx * lx + ly * ly) + 1e-300
        cond[i] = abs(tx * ly - ty * lx) / (tn * ln)
    return dirs, phi, cond


@njit(cache=True, nogil=True)
def _normalized_nb(uv, K, d, m_inv, iterations):
    """(n, 2) ideal normalized coordinates of the distorted pixels ``uv`` (n, 2): at most ``iterations``
    fixed-point steps of :func:`recon.distortion.undistort_step`; NaN where they did not settle."""
    n = uv.shape[0]
    xy = np.empty((n, 2))
    for i in range(n):
        yp = (uv[i, 1] - K[1, 2]) / K[1, 1]
        xp = (uv[i, 0] - K[0, 2] - K[0, 1] * yp) / K[0, 0]
        x0, y0 = _untilt_nb(xp, yp, d, m_inv)
        x = x0
        y = y0
        for _ in range(iterations):
            xn, yn = _undistort_step_nb(x, y, x0, y0, d)
            moved = abs(xn - x) + abs(yn - y)
            x = xn
            y = yn
            if not moved > 1e-14:  # as undistort_normalized's eps (NaN stops too)
                break
        else:
            x = y = np.nan  # not settled: the caller solves such points in Python (distortion's Newton steps)
        xy[i, 0] = x
        xy[i, 1] = y
    return xy


# ----------------------------------------------------------------------------- spline fits
@njit(cache=True, nogil=True)
def spline_fit_nb(idx, b, y, ok, w, P, smoothing):
    """Penalized least-squares coefficients of a uniform cubic B-spline from its banded design.

    Parameters
    ----------
    idx : (n,) int64 array
        First basis function of each row (:meth:`recon.subpixel.UniformSpline.basis`).
    b : (n, 4) float64 array
        Its four weights.
    y : (n, d) float64 array
        Values (their frame and units).
    ok : (n,) bool array
        Rows used.
    w : (n,) float64 array
        Row weights.
    P : (m, m) float64 array
        Penalty (m coefficients).
    smoothing : float
        Penalty weight relative to the mean diagonal of the normal matrix.

    Returns
    -------
    (m, d) float64 array
        The coefficients, in the units of ``y``.
    """
    m = P.shape[0]
    dim = y.shape[1]
    AtA = np.zeros((m, m))
    Aty = np.zeros((m, dim))
    for r in range(idx.shape[0]):
        if not ok[r]:
            continue
        i0 = idx[r]
        wr = w[r]
        for a in range(4):
            wa = b[r, a] * wr
            for c in range(4):
                AtA[i0 + a, i0 + c] += wa * b[r, c]
            for k in range(dim):
                Aty[i0 + a, k] += wa * y[r, k]
    tr = 0.0
    for a in range(m):
        tr += AtA[a, a]
    lam = smoothing * tr / m
    return np.linalg.solve(AtA + lam * P, Aty)


@njit(cache=True, nogil=True)
def spline_basis_nb(s, s0, h, n_int, deriv):
    """The four non-zero uniform cubic B-spline basis functions (or their first derivatives) at each ``s``.

    Parameters
    ----------
    s : (n,) float64 array
        Curve parameters (units of ``s0``).
    s0, h : float
        First knot and knot spacing.
    n_int : int
        Knot intervals (``n_int + 3`` coefficients).
    deriv : int
        0: the basis functions; 1: their derivatives (per unit of ``s``).

    Returns
    -------
    idx : (n,) int64 array
        First of the four coefficients each ``s`` uses.
    b : (n, 4) float64 array
        Their weights.
    """
    n = s.shape[0]
    idx = np.empty(n, np.int64)
    b = np.empty((n, 4))
    k = 1.0 / (2.0 * h)
    for r in range(n):
        x = (s[r] - s0) / h
        i = min(max(np.floor(x), 0.0), n_int - 1.0)
        idx[r] = np.int64(i)
        u = x - i
        u2 = u * u
        v = 1.0 - u
        if deriv == 0:
            u3 = u2 * u
            b[r, 0] = v * v * v / 6.0
            b[r, 1] = (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0
            b[r, 2] = (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0
            b[r, 3] = u3 / 6.0
        else:
            b[r, 0] = -v * v * k
            b[r, 1] = (3.0 * u2 - 4.0 * u) * k
            b[r, 2] = (-3.0 * u2 + 2.0 * u + 1.0) * k
            b[r, 3] = u2 * k
    return idx, b


@njit(cache=True, nogil=True)
def spline_eval_nb(idx, b, coef):
    """A uniform cubic B-spline (or its derivative) at the rows of its banded design.

    Parameters
    ----------
    idx : (n,) int64 array
        First basis function of each row.
    b : (n, 4) float64 array
        Its four weights (of the basis functions or of their derivatives).
    coef : (m, d) float64 array
        Coefficients.

    Returns
    -------
    (n, d) float64 array
        The values, in the units of ``coef`` (per unit of the curve parameter for a derivative).
    """
    n = idx.shape[0]
    dim = coef.shape[1]
    out = np.zeros((n, dim))
    for r in range(n):
        i0 = idx[r]
        for a in range(4):
            for k in range(dim):
                out[r, k] += b[r, a] * coef[i0 + a, k]
    return out


@njit(cache=True, nogil=True)
def spline_robust_nb(idx, b, y, ok, P, smoothing, min_px, n_sigma):
    """Fit; drop rows off the fit by more than max(n_sigma MAD, min_px); refit.

    Parameters
    ----------
    idx, b : (n,) int64 and (n, 4) float64 arrays
        The banded design (see :func:`spline_fit_nb`).
    y : (n, 2) float64 array
        Points (image frame, px).
    ok : (n,) bool array
        Rows used.
    P : (m, m) float64 array
        Penalty.
    smoothing : float
        Penalty weight (see :func:`spline_fit_nb`).
    min_px, n_sigma : float
        Rejection: residuals (px) of at least ``max(n_sigma * MAD, min_px)``.

    Returns
    -------
    coef : (m, 2) float64 array
        The coefficients after the refit (the first fit's when fewer than 4 rows remain).
    new_ok : (n,) bool array
        ``ok`` without the rejected rows.
    """
    w = np.ones(idx.shape[0])
    coef = spline_fit_nb(idx, b, y, ok, w, P, smoothing)
    fit = spline_eval_nb(idx, b, coef)
    n = idx.shape[0]
    res = np.empty(n)
    cnt = 0
    for r in range(n):
        dx = y[r, 0] - fit[r, 0]
        dy = y[r, 1] - fit[r, 1]
        res[r] = np.sqrt(dx * dx + dy * dy)
        if ok[r]:
            cnt += 1
    sel = np.empty(cnt)
    j = 0
    for r in range(n):
        if ok[r]:
            sel[j] = res[r]
            j += 1
    mad = 1.4826 * np.median(sel) + 1e-3
    lim = max(n_sigma * mad, min_px)
    new_ok = ok.copy()
    changed = 0
    for r in range(n):
        if ok[r] and res[r] >= lim:
            new_ok[r] = False
            changed += 1
    if changed > 0 and cnt - changed >= 4:
        coef = spline_fit_nb(idx, b, y, new_ok, w, P, smoothing)
    return coef, new_ok


# ----------------------------------------------------------------------------- background fits
@njit(cache=True, nogil=True)
def frame_coefficients_nb(frame_flat, sample_index, sample_mean, Bt, G, thr):
    """:func:`recon.subpixel.frame_coefficients`: least squares on the samples, then again without the foreground.

    Parameters
    ----------
    frame_flat : (H*W,) uint8 array
        The frame (gray levels), flattened.
    sample_index : (M, 4) int64 array
        Flat indices of the 2x2 pixels each coarse sample averages.
    sample_mean : (M,) float32 array
        Mean background at the samples.
    Bt : (M, k) float64 array
        Eigenbackgrounds at the samples.
    G : (k, k) float64 array
        ``Bt.T @ Bt`` plus the prior's diagonal.
    thr : (M,) float32 array
        Foreground threshold at the samples (gray levels); a residual over half of it leaves the second fit.

    Returns
    -------
    c : (k,) float64 array
        The coefficients ``c_1..c_k``.
    lo, hi : float
        The darkest and the brightest sampled pixel (gray levels), for
        :func:`recon.background.no_picture`.
    """
    M = sample_index.shape[0]
    k = Bt.shape[1]
    r = np.empty(M)
    lo = np.inf
    hi = -np.inf
    for i in range(M):
        v = 0.0
        for q in range(4):
            x = np.float64(frame_flat[sample_index[i, q]])
            v += x
            lo = min(lo, x)
            hi = max(hi, x)
        r[i] = 0.25 * v - sample_mean[i]
    rhs = np.zeros(k)
    for i in range(M):
        for j in range(k):
            rhs[j] += Bt[i, j] * r[i]
    c = np.linalg.solve(G, rhs)
    G2 = G.copy()
    rhs2 = rhs.copy()
    out = 0
    for i in range(M):
        e = r[i]
        for j in range(k):
            e -= Bt[i, j] * c[j]
        if abs(e) > 0.5 * thr[i]:
            out += 1
            for a in range(k):
                rhs2[a] -= Bt[i, a] * r[i]
                for b2 in range(k):
                    G2[a, b2] -= Bt[i, a] * Bt[i, b2]
    if out > 0:
        c = np.linalg.solve(G2, rhs2)
    return c, lo, hi


#: Side (px) of the mean background's patch kept around each pixel the shift is fitted on, and how far it
#: reaches above and to the left of that pixel: a shift of up to 3 px samples rows and columns -3..+4.
SHIFT_PATCH = 8
SHIFT_PATCH_BACK = 3


@njit(cache=True, nogil=True)
def frame_shift_nb(frame_flat, mean_flat, W, H, idx, D, G, iterations, patches):
    """:func:`recon.jitter.frame_shift` without the final plausibility check.

    Parameters
    ----------
    frame_flat : (H*W,) uint8 array
        The frame (gray levels), flattened.
    mean_flat : (H*W,) float32 array
        The mean background, flattened.
    W, H : int
        Image size (px).
    idx : (N,) int64 array
        Flat indices of the static edges' pixels.
    D : (N, 6) float64 array
        Regressors there (mean, 1, x * mean, y * mean, -d mean/du, -d mean/dv).
    G : (6, 6) float64 array
        ``D.T @ D``.
    iterations : int
        Gauss-Newton steps (each stops the search once the shift exceeds 3 px or is not finite).
    patches : (N, 8, 8) float32 array
        ``mean_flat`` around each pixel, from 3 px above and left of it (:data:`SHIFT_PATCH_BACK`): what a step
        re-samples, read in order (see :func:`_shift_normal_equations`).

    Returns
    -------
    du, dv : float
        The shift (image frame, px).
    """
    n = idx.shape[0]
    f = np.empty(n)
    for i in range(n):
        f[i] = frame_flat[idx[i]]
    rhs = np.zeros(6)
    for i in range(n):
        for a in range(6):
            rhs[a] += D[i, a] * f[i]
    beta = np.linalg.solve(G, rhs)
    res = np.empty(n)
    for i in range(n):
        e = f[i]
        for a in range(6):
            e -= D[i, a] * beta[a]
        res[i] = abs(e)
    s = 1.4826 * np.median(res) + 1e-6
    keep = res <= 4.0 * s
    G2 = G.copy()
    rhs2 = rhs.copy()
    nbad = 0
    for i in range(n):
        if not keep[i]:
            nbad += 1
            for a in range(6):
                rhs2[a] -= D[i, a] * f[i]
                for b2 in range(6):
                    G2[a, b2] -= D[i, a] * D[i, b2]
    if nbad > 0:
        beta = np.linalg.solve(G2, rhs2)
    if not beta[0] > 0.0:
        return np.nan, np.nan  # no positive gain: a black or inverted frame, nothing of the background to register
    du = beta[4] / beta[0]
    dv = beta[5] / beta[0]
    for _ in range(iterations):
        if not (np.isfinite(du) and np.isfinite(dv)) or du * du + dv * dv > 9.0:
            break
        GG, rr = _shift_normal_equations(f, keep, idx, mean_flat, W, H, du, dv, patches)
        beta = np.linalg.solve(GG, rr)
        if not beta[0] > 0.0:
            return np.nan, np.nan
        du += beta[4] / beta[0]
        dv += beta[5] / beta[0]
    return du, dv


@njit(cache=True, nogil=True)
def _shift_normal_equations(f, keep, idx, mean_flat, W, H, du, dv, patches):
    """Normal equations ``(GG (6, 6), rr (6,))`` of one Gauss-Newton step of :func:`frame_shift_nb`: the
    regressors re-sampled (bilinear) at the pixels ``idx[keep]`` moved back by the shift ``(du, dv)`` px,
    against the frame's values ``f`` there.

    The mean's four pixels come from each pixel's ``patches`` row (a shift of at most 3 px keeps them inside
    it), else from ``mean_flat``: the same values, but 3000 scattered pairs of cache lines of the
    background stack cost ~0.27 ms a view with cold caches (a frame's first pass, after other work), the
    patches read in order a fraction of that."""
    n = idx.shape[0]
    row = np.empty(6)
    GG = np.zeros((6, 6))
    rr = np.zeros(6)
    for i in range(n):
        if not keep[i]:
            continue
        p = idx[i]
        y = p // W
        x = p - y * W
        u = min(max(x - du, 0.0), W - 2.001)
        v = min(max(y - dv, 0.0), H - 2.001)
        u0 = int(np.floor(u))
        v0 = int(np.floor(v))
        fu = u - u0
        fv = v - v0
        a = v0 - y + SHIFT_PATCH_BACK
        b = u0 - x + SHIFT_PATCH_BACK
        if 0 <= a < SHIFT_PATCH - 1 and 0 <= b < SHIFT_PATCH - 1:
            m00 = patches[i, a, b]
            m01 = patches[i, a, b + 1]
            m10 = patches[i, a + 1, b]
            m11 = patches[i, a + 1, b + 1]
        else:
            q = v0 * W + u0
            m00 = mean_flat[q]
            m01 = mean_flat[q + 1]
            m10 = mean_flat[q + W]
            m11 = mean_flat[q + W + 1]
        mv = (1 - fv) * ((1 - fu) * m00 + fu * m01) + fv * ((1 - fu) * m10 + fu * m11)
        row[0] = mv
        row[1] = 1.0
        row[2] = (x / W - 0.5) * mv
        row[3] = (y / H - 0.5) * mv
        row[4] = -((1 - fv) * (m01 - m00) + fv * (m11 - m10))
        row[5] = -((1 - fu) * (m10 - m00) + fu * (m11 - m01))
        for a in range(6):
            rr[a] += row[a] * f[i]
            for b2 in range(a, 6):
                GG[a, b2] += row[a] * row[b2]
    # The lower triangle is the upper's: the same products, summed in the same order.
    for a in range(1, 6):
        for b2 in range(a):
            GG[a, b2] = GG[b2, a]
    return GG, rr


# ----------------------------------------------------------------------------- tip
@njit(cache=True, nogil=True)
def _axis_line_nb(frame, stack, coeff, p_end, t_end, off, nx, ny, back_px, step, d):
    """The background difference (bilinear, gray levels) into ``d`` along the line ``off`` px to the side
    (normal ``(nx, ny)``) of the axis through ``p_end`` along ``t_end``, from ``back_px`` behind it every
    ``step`` px; False when the line leaves the image (for :func:`tip_along_axis_nb`)."""
    H, W = frame.shape
    T = d.shape[0]
    k1 = coeff.shape[0]
    good = True
    for j in range(T):
        t = -back_px + j * step
        u = p_end[0] + t * t_end[0] + off * nx
        v = p_end[1] + t * t_end[1] + off * ny
        if u < 0 or v < 0 or u > W - 1 or v > H - 1:
            good = False
            break
        u = min(u, W - 1.001)
        v = min(v, H - 1.001)
        u0 = int(np.floor(u))
        v0 = int(np.floor(v))
        fu = u - u0
        fv = v - v0
        acc = 0.0
        for du in range(2):
            for dv in range(2):
                wgt = (fu if du else 1 - fu) * (fv if dv else 1 - fv)
                p = (v0 + dv) * W + u0 + du
                bg = 0.0
                for c in range(k1):
                    bg += stack[p, c] * coeff[c]
                acc += wgt * (frame.flat[p] - bg)
        d[j] = acc
    return good


@njit(cache=True, nogil=True)
def tip_along_axis_nb(frame, stack, coeff, p_end, t_end, radius_px, threshold, back_px, ahead_px, step):
    """``recon.subpixel._tip_along_axis``: the silhouette's end along the tube's axis.

    Parameters
    ----------
    frame : (H, W) uint8 array
        The frame (gray levels).
    stack, coeff : arrays
        The background model and the frame's coefficients (see the module).
    p_end, t_end : (2,) float64 arrays
        The last centre (image frame, px) and the unit tangent there.
    radius_px : float
        The tube's half-width (px); five lines parallel to the axis lie within it.
    threshold : float
        Edge threshold of one line (gray levels).
    back_px, ahead_px, step : float
        The lines run from ``back_px`` behind ``p_end`` to ``ahead_px`` beyond it, sampled every ``step`` (px).

    Returns
    -------
    float
        The median end over the lines (px along ``t_end`` from ``p_end``), NaN if no line has one.
    """
    nx, ny = -t_end[1], t_end[0]
    offs = np.array([-0.45, -0.2, 0.0, 0.2, 0.45]) * radius_px
    T = int(np.floor((ahead_px + back_px) / step + 1e-9)) + 1
    n_in = int(round(2.0 / step))
    ends = np.empty(5)
    n_end = 0
    d = np.empty(T)
    for li in range(5):
        if not _axis_line_nb(frame, stack, coeff, p_end, t_end, offs[li], nx, ny, back_px, step, d):
            continue
        last = -1
        cnt_above = 0
        for j in range(T):
            if abs(d[j]) > threshold:
                last = j
        if last < 0:
            continue
        j0 = last - n_in
        if j0 < 2 or last > T - 4:
            continue
        for j in range(j0 + 1):
            if abs(d[j]) > threshold:
                cnt_above += 1
        if not cnt_above > 0.7 * (j0 + 1):
            continue
        sgn = 1.0 if d[last] > 0 else -1.0
        ref = -1e30
        for j in range(j0 - 2, j0 + n_in + 1):
            if d[j] * sgn > ref:
                ref = d[j] * sgn
        if ref <= threshold:
            continue
        cov = 0.0
        for j in range(j0 + 1, j0 + n_in + 5):
            jj = min(j, T - 1)
            a = d[jj] * sgn / ref
            cov += 0.0 if a < 0.0 else (1.0 if a > 1.0 else a)
        ends[n_end] = -back_px + j0 * step + 0.5 * step + step * cov
        n_end += 1
    if n_end == 0:
        return np.nan
    return np.median(ends[:n_end])


@njit(cache=True, nogil=True)
def project_nb(P, K, d, m, T):
    """World points -> distorted pixels and depths, as :meth:`recon.camera.Camera.project`.

    Parameters
    ----------
    P : (n, 3) float64 array
        Points (world frame, mm).
    K : (3, 3) array
        The camera matrix.
    d : (14,) array
        The distortion coefficients (OpenCV order).
    m : (3, 3) array
        The tilt matrix.
    T : (4, 4) array
        World -> camera transform (mm).

    Returns
    -------
    uv : (n, 2) float64 array
        Pixels (image frame, px).
    z : (n,) float64 array
        Depths along the optical axis (camera frame, mm).
    """
    n = P.shape[0]
    uv = np.empty((n, 2))
    z = np.empty(n)
    for i in range(n):
        xc = T[0, 0] * P[i, 0] + T[0, 1] * P[i, 1] + T[0, 2] * P[i, 2] + T[0, 3]
        yc = T[1, 0] * P[i, 0] + T[1, 1] * P[i, 1] + T[1, 2] * P[i, 2] + T[1, 3]
        zc = T[2, 0] * P[i, 0] + T[2, 1] * P[i, 1] + T[2, 2] * P[i, 2] + T[2, 3]
        z[i] = zc
        xd, yd = _distort_nb(xc / zc, yc / zc, d, m)
        uv[i, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        uv[i, 1] = K[1, 1] * yd + K[1, 2]
    return uv, z


@njit(cache=True, nogil=True)
def _windows(seeds, tangents, half, nav_max, H, W):
    """Per seed: profile axis (1: along u, for a tube running along v), window centre (cu, cv) kept
    ``half`` px inside the image along the profile, lines to average (fewer where the tube is slanted
    to them), and whether the centre stayed the rounded seed."""
    n = seeds.shape[0]
    axis = np.zeros(n, np.int8)
    cu = np.empty(n, np.int64)
    cv = np.empty(n, np.int64)
    nav = np.empty(n, np.int64)
    inside = np.empty(n, np.bool_)
    for i in range(n):
        tx = abs(tangents[i, 0])
        ty = abs(tangents[i, 1])
        ax = ty > tx
        axis[i] = 1 if ax else 0
        nav[i] = min(nav_max, int(np.floor(max(tx, ty) / max(min(tx, ty), 1e-6) + 1e-9)))
        u0 = int(np.rint(seeds[i, 0]))
        v0 = int(np.rint(seeds[i, 1]))
        if ax:
            u = min(max(u0, half), W - 1 - half)
            v = min(max(v0, 0), H - 1)
        else:
            u = min(max(u0, 0), W - 1)
            v = min(max(v0, half), H - 1 - half)
        cu[i] = u
        cv[i] = v
        inside[i] = u == u0 and v == v0
    return axis, cu, cv, nav, inside


@njit(cache=True, nogil=True)
def profiles_at_seeds_nb(frame, stack, coeff, seeds, tangents, half, threshold, nav_max, threshold1, strong):
    """:func:`recon.subpixel.edges_from_profiles` in one call: windows, lines averaged, edges, centres.

    Parameters
    ----------
    frame, stack, coeff : arrays
        The frame and the background model (see the module).
    seeds, tangents : (n, 2) float64 arrays
        Profile centres (image frame, px) and the tube's unit direction there.
    half : int
        Half-length of the profiles (px).
    threshold, threshold1, strong : float
        As for :func:`profile_edges_nb` (gray levels).
    nav_max : int
        Most lines averaged on each side (fewer where the tube is slanted to them).

    Returns
    -------
    centers : (n, 2) float64 array
        Midpoints of the edges (image frame, px).
    chord : (n,) float64 array
        Edge distance along the profile (px).
    axis : (n,) int8 array
        1: the profile runs along u, 0: along v.
    ok : (n,) bool array
        Edges found and the window centred on the rounded seed.
    """
    H, W = frame.shape
    n = seeds.shape[0]
    axis, cu, cv, nav, inside = _windows(seeds, tangents, half, nav_max, H, W)
    e1, e2, ok, _ = profile_edges_nb(frame, stack, coeff, cu, cv, axis, half, threshold, nav, threshold1, strong)
    centers = np.empty((n, 2))
    chord = np.empty(n)
    for i in range(n):
        ok[i] = ok[i] and inside[i]
        mid = 0.5 * (e1[i] + e2[i]) - half
        if axis[i]:
            centers[i, 0] = cu[i] + mid
            centers[i, 1] = cv[i]
        else:
            centers[i, 0] = cu[i]
            centers[i, 1] = cv[i] + mid
        chord[i] = e2[i] - e1[i]
    return centers, chord, axis, ok


@njit(cache=True, nogil=True)
def profile_values_nb(frame, stack, coeff, seeds, tangents, half, nav_max):
    """Background differences on the profiles at ``seeds``, each the mean of its lines.

    The windows and lines of :func:`profiles_at_seeds_nb` (seeds rounded and
    kept inside the image).

    Parameters
    ----------
    frame, stack, coeff : arrays
        The frame and the background model (see the module).
    seeds, tangents : (n, 2) float64 arrays
        Profile centres (image frame, px) and the tube's unit direction there.
    half : int
        Half-length of the profiles (px).
    nav_max : int
        Most lines averaged on each side.

    Returns
    -------
    (n, 2 half + 1) float64 array
        The differences (gray levels), sample ``half`` at the window's centre.
    """
    H, W = frame.shape
    n = seeds.shape[0]
    L = 2 * half + 1
    out = np.zeros((n, L))
    axis, cu, cv, nav, _ = _windows(seeds, tangents, half, nav_max, H, W)
    for i in range(n):
        cnt = 0
        for o in range(-nav[i], nav[i] + 1):
            if _add_line(out[i], frame, stack, coeff, cu[i], cv[i], axis[i] == 1, half, o, H, W):
                cnt += 1
        if cnt > 0:
            for j in range(L):
                out[i, j] /= cnt
    return out


@njit(cache=True, nogil=True)
def ridge_hits_nb(d, w, max_off, half, threshold):
    """Per profile of ``|difference|`` values: the tube's core as a ridge (see ``recon.subpixel._energy_hits``).

    Parameters
    ----------
    d : (n, L) float64 array
        Absolute differences from the background (gray levels), sample ``half`` at the seed.
    w : int
        Window width: the tube's width (px).
    max_off : (n,) float64 array
        Farthest the window's centre may lie from the seed (px).
    half : float
        Index of the seed's sample.
    threshold : float
        Edge threshold (gray levels); the window's mean must exceed the
        profile's median by half of it, and be twice that median.

    Returns
    -------
    found : (n,) bool array
        Profiles whose best window is such a ridge.
    off : (n,) float64 array
        Centroid of the window's differences, from the seed (px along the profile).
    """
    n, L = d.shape
    m = L - w + 1
    found = np.zeros(n, np.bool_)
    off = np.zeros(n)
    c = np.zeros(L + 1)
    for i in range(n):
        for k in range(L):
            c[k + 1] = c[k] + d[i, k]
        best = -np.inf
        j = 0
        for k in range(m):
            if abs(k + 0.5 * (w - 1) - half) <= max_off[i]:
                v = (c[k + w] - c[k]) / w
                if v > best:
                    best = v
                    j = k
        level = np.median(d[i])
        found[i] = (best - level > 0.5 * threshold) and (best > 2.0 * level)
        sw = 0.0
        swc = 0.0
        for q in range(j - 1, j + w + 1):
            col = min(max(q, 0), L - 1)
            sw += d[i, col]
            swc += d[i, col] * col
        off[i] = swc / max(sw, 1e-9) - half
    return found, off


@njit(cache=True, nogil=True)
def near_any_nb(points, visited, radius):
    """Which points lie within ``radius`` of one of the visited points.

    Parameters
    ----------
    points : (n, 2) float64 array
        Points (image frame, px).
    visited : (m, 2) float64 array
        Points visited before (image frame, px).
    radius : float
        Distance (px); strictly less counts.

    Returns
    -------
    (n,) bool array
    """
    out = np.zeros(points.shape[0], np.bool_)
    r2 = radius * radius
    for i in range(points.shape[0]):
        for k in range(visited.shape[0]):
            du = points[i, 0] - visited[k, 0]
            dv = points[i, 1] - visited[k, 1]
            if du * du + dv * dv < r2:
                out[i] = True
                break
    return out


@njit(cache=True, nogil=True)
def polyline_distances_nb(points, polyline):
    """Distance from each point to a polyline, and the segment where it is nearest.

    Parameters
    ----------
    points : (n, 2) float64 array
        Points (image frame, px).
    polyline : (m, 2) float64 array, m >= 2
        Vertices in order (image frame, px).

    Returns
    -------
    d : (n,) float64 array
        Distances (px), as :func:`recon.metrics.point_to_polyline_distances`.
    seg : (n,) int64 array
        Index of the nearest segment (0 .. m - 2).
    """
    n, m = points.shape[0], polyline.shape[0]
    d = np.empty(n)
    seg = np.zeros(n, np.int64)
    for i in range(n):
        best = np.inf
        for k in range(m - 1):
            ax, ay = polyline[k, 0], polyline[k, 1]
            bx, by = polyline[k + 1, 0] - ax, polyline[k + 1, 1] - ay
            px, py = points[i, 0] - ax, points[i, 1] - ay
            ab2 = bx * bx + by * by
            t = 0.0 if ab2 <= 0.0 else min(max((px * bx + py * by) / ab2, 0.0), 1.0)
            ex, ey = px - t * bx, py - t * by
            e2 = ex * ex + ey * ey
            if e2 < best:
                best = e2
                seg[i] = k
        d[i] = np.sqrt(best)
    return d, seg


@njit(cache=True, nogil=True)
def running_rank_nb(x, size, rank):
    """The ``rank``-th smallest (0-based) of each window of ``size`` values centred on each of ``x``.

    The windows of :func:`scipy.ndimage.rank_filter` with ``mode="nearest"``
    (the end values repeated beyond the ends; ``size`` odd): a running
    median is ``rank = size // 2``. Compiled because the profiles' widths are
    filtered on every frame and the SciPy call costs ~50x the work here. NaN
    values are not allowed.

    Parameters
    ----------
    x : (n,) float64 array
    size : int
        Window length (odd).
    rank : int
        0 <= rank < size.

    Returns
    -------
    (n,) float64 array
    """
    n = x.shape[0]
    h = size // 2
    out = np.empty(n)
    if n == 0:
        return out
    # The window kept sorted as it slides: one value leaves and one enters per step (O(size), no sort).
    buf = np.empty(size)
    for j in range(size):
        buf[j] = x[min(max(j - h, 0), n - 1)]
    buf.sort()
    out[0] = buf[rank]
    for i in range(1, n):
        _replace_sorted(buf, x[min(max(i - 1 - h, 0), n - 1)], x[min(i + h, n - 1)])
        out[i] = buf[rank]
    return out


@njit(cache=True, nogil=True, inline="always")
def _replace_sorted(buf, old, new):
    """Replace a value ``old`` of the sorted window ``buf`` by ``new``, keeping it sorted (O(len(buf)), no sort)."""
    size = buf.shape[0]
    k = 0
    while buf[k] != old:
        k += 1
    while k > 0 and buf[k - 1] > new:
        buf[k] = buf[k - 1]
        k -= 1
    while k < size - 1 and buf[k + 1] < new:
        buf[k] = buf[k + 1]
        k += 1
    buf[k] = new


@njit(cache=True, nogil=True)
def median_nb(x):
    """:func:`numpy.median` of a 1-D float64 array, the same value (the mean of the middle two for an even
    count), compiled: about 1 us where NumPy's costs about 20 (wide suite's frames: a dozen medians of a few
    tens of widths and distances per pair, 0.2 ms). NaN values are not allowed.

    Parameters
    ----------
    x : (n,) float64 array
        The values (any unit, e.g. px).

    Returns
    -------
    float
        Their median, in their unit; NaN for an empty array.
    """
    if x.shape[0] == 0:
        return np.nan
    return np.median(x)


@njit(cache=True, nogil=True)
def max_window_median_nb(x, size):
    """The largest median of the windows of ``size`` consecutive values of ``x`` (1-D float64): NumPy's
    ``np.median(sliding_window_view(x, size), axis=1).max()``, the same value, compiled (about 80 us in NumPy
    on a backbone's 200 distances). NaN values are not allowed.

    Parameters
    ----------
    x : (n,) float64 array
        The values in order (any unit, e.g. px from a centerline along a backbone).
    size : int
        Window length (>= 1).

    Returns
    -------
    float
        The largest of the windows' medians, in the unit of ``x``; -inf where ``x`` is shorter than ``size``.
    """
    n = x.shape[0]
    if n < size:
        return -np.inf
    # The window kept sorted as it slides: one value leaves and one enters per step.
    buf = np.sort(x[:size])
    h = size // 2
    best = buf[h] if size % 2 else (buf[h - 1] + buf[h]) / 2
    for i in range(1, n - size + 1):
        _replace_sorted(buf, x[i - 1], x[i + size - 1])
        m = buf[h] if size % 2 else (buf[h - 1] + buf[h]) / 2
        if m > best:
            best = m
    return best


@njit(cache=True, nogil=True)
def best_path_nb(score, points, step_mm, start, stretch_cost, max_stretch):
    """:func:`recon.guided.best_path`'s dynamic programme, compiled.

    The same values, step bound and tie-breaking (the first of equal
    predecessors) as the NumPy form kept in ``tests/fast_oracles.py``, which
    built a (n, n, 3) array per ray: ~0.8 s for 120 rays of 288 candidates
    against a few tens of ms here.

    Parameters
    ----------
    score : (K, n) float64 array
        Each candidate's score.
    points : (K, n, 3) float64 array
        The candidates (world, mm).
    step_mm : (K,) float64 array
        The least length of each step (mm).
    start : (3,) float64 array
        Where the path starts (world, mm).
    stretch_cost, max_stretch : float
        As in :func:`recon.guided.best_path`.

    Returns
    -------
    found : bool
        False where no path keeps to the step bound.
    path : (K,) int64 array
        The chosen candidate's index on each ray (zeros where not found).
    """
    K, n = score.shape
    value = np.empty(n)
    for j in range(n):
        d2 = 0.0
        for c in range(3):
            e = points[0, j, c] - start[c]
            d2 += e * e
        value[j] = score[0, j] if np.sqrt(d2) <= max_stretch * step_mm[0] + 1e-9 else -np.inf
    back = np.zeros((K, n), np.int64)
    new = np.empty(n)
    limit = max_stretch - 1.0
    for k in range(1, K):
        sk = max(step_mm[k], 1e-6)
        for i in range(n):
            best = -np.inf
            bi = 0
            for j in range(n):
                if value[j] == -np.inf:
                    continue
                d2 = 0.0
                for c in range(3):
                    e = points[k, i, c] - points[k - 1, j, c]
                    d2 += e * e
                excess = np.sqrt(d2) / sk - 1.0
                if excess > limit:
                    continue
                t = value[j] - stretch_cost * max(excess, 0.0)
                if t > best:
                    best = t
                    bi = j
            back[k, i] = bi
            new[i] = score[k, i] + best
        value[:] = new
    path = np.zeros(K, np.int64)
    top = -np.inf
    for j in range(n):
        if value[j] > top:
            top = value[j]
            path[K - 1] = j
    if not np.isfinite(top):
        return False, path
    for k in range(K - 1, 0, -1):
        path[k - 1] = back[k, path[k]]
    return True, path
