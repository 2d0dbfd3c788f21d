"""NumPy oracles of the fast method's compiled kernels (recon._kernels), for the tests only.

The fast method runs one path, compiled with numba. These are the NumPy
versions it was written against, plain array code that is easy to read and
check by eye: the tests compare each kernel with its oracle, and a whole
reconstruction with every kernel swapped for its oracle (:func:`use_numpy_path`).
Each function takes the arguments of the production function it stands for
(named in its docstring) and returns the same values, to rounding.
"""
from __future__ import annotations

import cv2
import numpy as np

from recon import fast, subpixel
from recon.background import no_picture
from recon.errors import FrameError
from recon.metrics import backbone_errors

__all__ = [
    "frame_shift", "frame_coefficients", "coarse_foreground", "geodesic_path", "bfs_path", "traced_path", "gather_profiles",
    "profile_edges", "edges_from_profiles", "design", "fit_curve", "Fitter", "bilinear_diff", "tip_along_axis",
    "near", "energy_hits", "project", "best_path", "use_numpy_path", "compiled_and_oracle", "assert_agree",
]


# ----------------------------------------------------------------------------- background
def frame_shift(model, frame: np.ndarray, max_px: float = 3.0, iterations: int = 1) -> np.ndarray:
    """:func:`recon.jitter.frame_shift`: image shift (du, dv) px of a frame against the mean background
    (``model``: a :class:`recon.jitter.ShiftModel` or None)."""
    if model is None:
        return np.zeros(2)
    D = model.design
    f = np.take(frame.reshape(-1), model.index).astype(np.float64)
    beta = np.linalg.solve(model.gram, D.T @ f)
    r = f - D @ beta
    s = 1.4826 * float(np.median(np.abs(r))) + 1e-6
    bad = np.abs(r) > 4.0 * s
    if bad.any():
        Db = D[bad]
        beta = np.linalg.solve(model.gram - Db.T @ Db, D.T @ f - Db.T @ f[bad])
    d = beta[4:] / beta[0]  # the shifted mean is scaled by the gain too
    for _ in range(iterations):
        # Gauss-Newton: regressors re-sampled at the shifted positions, for the remaining shift.
        if not np.all(np.isfinite(d)) or float(np.hypot(d[0], d[1])) > max_px:
            break
        D2 = _shifted_design(model, d)
        keep = ~bad
        G2 = D2[keep].T @ D2[keep]
        beta = np.linalg.solve(G2, D2[keep].T @ f[keep])
        d = d + beta[4:] / beta[0]
    if not np.all(np.isfinite(d)) or float(np.hypot(d[0], d[1])) > max_px:
        return np.zeros(2)
    return d


def _shifted_design(model, d: np.ndarray) -> np.ndarray:
    """:attr:`recon.jitter.ShiftModel.design` with the mean and its gradients taken at ``p - d`` (bilinear)."""
    H, W = model.shape
    idx = model.index
    y, x = np.divmod(idx, W)
    u = np.clip(x - d[0], 0, W - 2.001)
    v = np.clip(y - d[1], 0, H - 2.001)
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    m = model.mean
    base = v0 * W + u0
    m00, m01, m10, m11 = m[base], m[base + 1], m[base + W], m[base + W + 1]
    mv = (1 - fv) * ((1 - fu) * m00 + fu * m01) + fv * ((1 - fu) * m10 + fu * m11)
    D = model.design.copy()
    D[:, 0] = mv
    D[:, 2] = (x / W - 0.5) * mv
    D[:, 3] = (y / H - 0.5) * mv
    D[:, 4] = -((1 - fv) * (m01 - m00) + fv * (m11 - m10))
    D[:, 5] = -((1 - fu) * (m10 - m00) + fu * (m11 - m01))
    return D


def frame_coefficients(model, frame: np.ndarray) -> np.ndarray:
    """:func:`recon.subpixel.frame_coefficients`: ``[1, c_1..c_k]`` float32 of a frame."""
    samples = np.take(frame.reshape(-1), model.sample_index)
    why = no_picture(samples, model.peak, model.background_range)
    if why:
        raise FrameError(why, model.name)
    fs = samples.sum(axis=1, dtype=np.float64) * 0.25
    r = fs - model.sample_mean
    Bt = model.sample_basis_t
    rhs = Bt.T @ r
    G = model.sample_gram + np.diag(model.sample_prior)
    c = np.linalg.solve(G, rhs)
    out = np.abs(r - Bt @ c) > 0.5 * model.sample_threshold
    if out.any():
        Bo = Bt[out]
        try:
            c = np.linalg.solve(G - Bo.T @ Bo, rhs - Bo.T @ r[out])
        except np.linalg.LinAlgError:
            pass  # the first fit stands
    return np.concatenate([[1.0], c]).astype(np.float32)


# ----------------------------------------------------------------------------- coarse stage
def coarse_foreground(model, frame: np.ndarray, coeff: np.ndarray, box: tuple) -> tuple:
    """``recon.subpixel._coarse_foreground``: ``(mask uint8, any foreground, largest excess)`` of ``box``."""
    f = model.factor
    hc, wc = model.coarse_shape
    rx0, ry0, rx1, ry1 = box
    k = model.coarse_basis.shape[0]
    fc = subpixel._downsample(frame[ry0 * f: ry1 * f, rx0 * f: rx1 * f], f).astype(np.float32)
    basis = model.coarse_basis.reshape(k, hc, wc)[:, ry0:ry1, rx0:rx1]
    res = fc - model.coarse_mean.reshape(hc, wc)[ry0:ry1, rx0:rx1] - np.tensordot(coeff[1:], basis, axes=1)
    thr = model.coarse_threshold[ry0:ry1, rx0:rx1]
    excess = np.abs(res) - thr
    fg = excess > 0
    reach = subpixel._ABS_REACH
    near_fg = cv2.dilate(fg.view(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)).view(bool) & ~fg
    if near_fg.any():
        abs_excess = subpixel.coarse_abs_difference(model, frame, coeff, box) - thr
        fg |= near_fg & (abs_excess > 0)
        excess = np.where(near_fg, np.maximum(excess, abs_excess), excess)
    peak = float(excess.max()) if excess.size else 0.0
    return fg.view(np.uint8).copy(), bool(fg.any()), peak


_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def geodesic_path(mask: np.ndarray, start: tuple) -> np.ndarray:
    """Shortest 8-connected path inside ``mask`` from ``start`` (y, x) to the farthest pixel; (n, 2) (y, x).

    Breadth-first (hop count); among the pixels at the largest hop count the
    one farthest from ``start`` is the end (:func:`recon._kernels.bfs_path_nb`).
    """
    ys, xs = np.nonzero(mask)
    n = ys.size
    h, w = mask.shape
    index = np.full((h + 2, w + 2), -1, np.int32)
    index[ys + 1, xs + 1] = np.arange(n, dtype=np.int32)
    nb = np.stack([index[ys + 1 + dy, xs + 1 + dx] for dy, dx in _NEIGHBOURS], axis=1).tolist()
    s = int(index[start[0] + 1, start[1] + 1])
    pred = [-2] * n
    pred[s] = -1
    frontier = last = [s]
    while frontier:
        nxt = []
        for node in frontier:
            for m in nb[node]:
                if m >= 0 and pred[m] == -2:
                    pred[m] = node
                    nxt.append(m)
        if nxt:
            last = nxt
        frontier = nxt
    la = np.asarray(last)
    node = int(la[np.argmax((ys[la] - start[0]) ** 2 + (xs[la] - start[1]) ** 2)])
    path = [node]
    while pred[node] >= 0:
        node = pred[node]
        path.append(node)
    p = np.asarray(path[::-1])
    return np.stack([ys[p], xs[p]], axis=1)


def bfs_path(mask: np.ndarray, sy: int, sx: int) -> np.ndarray:
    """:func:`geodesic_path` with the arguments of :func:`recon._kernels.bfs_path_nb`."""
    return geodesic_path(mask.astype(bool), (sy, sx))


def traced_path(mask: np.ndarray, rect: tuple, origin: tuple, coarse_shape: tuple, base: tuple, ahead=None) -> tuple:
    """``recon.subpixel._traced_path`` (:func:`recon._kernels.traced_path_nb`) in NumPy: the region, pooled 2x2,
    its pixel nearest the base and :func:`bfs_path` from there."""
    sx, sy, sw, sh = rect
    rx0, ry0 = origin
    hc, wc = coarse_shape
    bx, by = base
    # The path is traced on the region pooled 2x2 (4x fewer graph nodes; the fine stage re-centres).
    x0p, y0p = sx - (sx & 1), sy - (sy & 1)
    x1p, y1p = min(wc, sx + sw + ((sx + sw) & 1)), min(hc, sy + sh + ((sy + sh) & 1))
    region = np.zeros((y1p - y0p, x1p - x0p), np.uint8)
    region[sy - y0p: sy - y0p + sh, sx - x0p: sx - x0p + sw] = mask[sy - ry0: sy - ry0 + sh, sx - rx0: sx - rx0 + sw] == 2
    if ahead is not None:
        axis, margin = ahead
        xx, yy = np.arange(x0p, x1p)[None, :], np.arange(y0p, y1p)[:, None]  # broadcast, not a full grid
        behind = (xx - bx) * axis[0] + (yy - by) * axis[1] < -margin
        if (region & ~behind).sum() >= 2:
            region &= ~behind
    ph, pw = region.shape[0] // 2, region.shape[1] // 2
    if ph and pw:
        rr = region[: 2 * ph, : 2 * pw]
        pooled = rr[0::2, 0::2] | rr[1::2, 0::2] | rr[0::2, 1::2] | rr[1::2, 1::2]
    else:
        pooled = region
    if pooled.size == 0 or not pooled.any():
        g, x0p, y0p = 1, sx, sy  # degenerate (tiny) region: no pooling
        pooled = region = (mask[sy - ry0:sy - ry0 + sh, sx - rx0:sx - rx0 + sw] == 2).view(np.uint8)
    else:
        g = 2
    ry, rx = np.nonzero(pooled)
    k0 = int(np.argmin(((rx + 0.5) * g + x0p - 0.5 - bx) ** 2 + ((ry + 0.5) * g + y0p - 0.5 - by) ** 2))
    path = bfs_path(np.ascontiguousarray(pooled, dtype=np.uint8), int(ry[k0]), int(rx[k0]))
    return path, g, region, x0p, y0p


# ----------------------------------------------------------------------------- profiles
def gather_profiles(model, frame: np.ndarray, coeff: np.ndarray, seeds: np.ndarray, tangents: np.ndarray, half: int,
                    nav=0) -> tuple:
    """Background differences on the profiles (n, 2 half + 1), each the mean of ``2 nav + 1`` parallel lines.

    Returns ``(d, axis int8, cu, cv, full)``: the profiles, their axes (1:
    along u), window centres (px) and whether the window stayed at the seed
    (``recon._kernels._windows`` and ``profile_values_nb``).
    """
    H, W = model.shape
    axis = np.abs(tangents[:, 1]) > np.abs(tangents[:, 0])  # True: tube runs vertically -> row profile
    cu = np.rint(seeds[:, 0]).astype(np.int64)
    cv = np.rint(seeds[:, 1]).astype(np.int64)
    cuc = np.where(axis, np.clip(cu, half, W - 1 - half), np.clip(cu, 0, W - 1))
    cvc = np.where(axis, np.clip(cv, 0, H - 1), np.clip(cv, half, H - 1 - half))
    full = (cuc == cu) & (cvc == cv)
    stride = np.where(axis, 1, W)
    acc = np.zeros((len(seeds), 2 * half + 1), np.float32)
    cnt = np.zeros(len(seeds), np.float32)
    nav = np.broadcast_to(np.asarray(nav, np.int64), (len(seeds),))
    for o in range(-int(nav.max(initial=0)), int(nav.max(initial=0)) + 1):
        ou, ov = np.where(axis, 0, o), np.where(axis, o, 0)
        inside = (np.abs(o) <= nav) & (cuc + ou >= 0) & (cuc + ou < W) & (cvc + ov >= 0) & (cvc + ov < H)
        idx = (np.clip(cvc + ov, 0, H - 1) * W + np.clip(cuc + ou, 0, W - 1))[:, None] + stride[:, None] * np.arange(-half, half + 1)
        d = np.take(frame.reshape(-1), idx).astype(np.float32)
        d -= (np.take(model.stack, idx.reshape(-1), axis=0) @ coeff).reshape(idx.shape)
        acc += np.where(inside[:, None], d, 0.0)
        cnt += inside
    return acc / cnt[:, None], axis.astype(np.int8), cuc, cvc, full


def profile_edges(d: np.ndarray, threshold: float, rims: bool = False):
    """Sub-pixel edges of the tube on profiles ``d`` (n, L): signed differences from the background.

    Returns ``(e1, e2, ok)`` (and the weaker rim contrast with ``rims``):
    edge positions in sample units (0 = first sample's centre), as
    ``recon._kernels._edges_1d`` per profile.
    """
    n, L = d.shape
    a = np.abs(d) > threshold
    has = a.any(axis=1)
    i1 = np.argmax(a, axis=1)
    i2 = L - 1 - np.argmax(a[:, ::-1], axis=1)
    ok = has & (i1 >= 2) & (i2 <= L - 3) & (i2 - i1 >= 1)
    i1 = np.where(ok, i1, 2)
    i2 = np.where(ok, i2, L - 3)
    rows = np.arange(n)[:, None]
    # Rim contrast: the same-signed extreme of the first 3 pixels from each edge inward.
    in1 = d[rows, i1[:, None] + np.arange(3)]
    in2 = d[rows, i2[:, None] - np.arange(3)]
    s1 = np.sign(d[np.arange(n), i1])
    s2 = np.sign(d[np.arange(n), i2])
    rim1 = s1 * np.max(in1 * s1[:, None], axis=1)
    rim2 = s2 * np.max(in2 * s2[:, None], axis=1)
    ok &= (np.abs(rim1) > threshold) & (np.abs(rim2) > threshold)
    rim1 = np.where(ok, rim1, 1.0)
    rim2 = np.where(ok, rim2, 1.0)
    # Partial pixels: i-1, i, i+1 on each side.
    w1 = np.clip(d[rows, i1[:, None] + np.arange(-1, 2)] / rim1[:, None], 0.0, 1.0).sum(axis=1)
    w2 = np.clip(d[rows, i2[:, None] - np.arange(-1, 2)] / rim2[:, None], 0.0, 1.0).sum(axis=1)
    e1 = i1 + 1.5 - w1
    e2 = i2 - 1.5 + w2
    if rims:
        return e1, e2, ok, np.where(ok, np.minimum(np.abs(rim1), np.abs(rim2)), 0.0)
    return e1, e2, ok


def edges_from_profiles(model, frame, coeff, seeds, tangents, s, half, threshold, nav: int = 0,
                        threshold1: float | None = None, strong: float = np.inf) -> subpixel.Profiles:
    """:func:`recon.subpixel.edges_from_profiles`: profiles at ``seeds`` and their edges."""
    tangents = np.asarray(tangents, np.float64)
    major = np.maximum(np.abs(tangents[:, 0]), np.abs(tangents[:, 1]))
    minor = np.minimum(np.abs(tangents[:, 0]), np.abs(tangents[:, 1]))
    nav = np.minimum(int(nav), np.floor(major / np.maximum(minor, 1e-6) + 1e-9)).astype(np.int64)
    thr1 = float(threshold if threshold1 is None else threshold1)
    strong = float(strong)
    if np.isfinite(strong) and nav.max(initial=0) > 0:
        d, axis, cu, cv, full = gather_profiles(model, frame, coeff, seeds, tangents, half, 0)
        e1, e2, ok, rim = profile_edges(d, thr1, rims=True)
        # Not averaged: strong single-line edges, and profiles without one sample beyond the mean's threshold.
        rest = np.flatnonzero(~((nav > 0) & ((ok & (rim >= strong)) | ~(np.abs(d) > threshold).any(axis=1))))
    else:
        d, axis, cu, cv, full = gather_profiles(model, frame, coeff, seeds, tangents, half, nav)
        e1, e2, ok = profile_edges(d, threshold)
        rest = np.zeros(0, np.int64)
    if rest.size:
        d = gather_profiles(model, frame, coeff, seeds[rest], tangents[rest], half, nav[rest])[0]
        e1[rest], e2[rest], ok[rest] = profile_edges(d, threshold)
    ok &= full
    mid = (e1 + e2) / 2.0 - half
    centers = np.stack([np.where(axis == 1, cu + mid, cu), np.where(axis == 1, cv, cv + mid)], axis=1).astype(np.float64)
    return subpixel.Profiles(centers=centers, chord=(e2 - e1), axis=axis, s=s, ok=ok)


# ----------------------------------------------------------------------------- splines
def design(s: np.ndarray, s0: float, h: float, n_int: int, deriv: int = 0) -> np.ndarray:
    """(n, n_int + 3) dense design matrix of :class:`recon.subpixel.UniformSpline` (or of its derivative)."""
    i, b = subpixel.UniformSpline.basis(s, s0, h, n_int, deriv)
    A = np.zeros((s.size, n_int + 3))
    A[np.arange(s.size)[:, None], i[:, None] + np.arange(4)] = b
    return A


def fit_curve(s: np.ndarray, y: np.ndarray, spacing: float, w=None, smoothing: float = 1e-4):
    """:func:`recon.subpixel.fit_curve` from the dense design matrix."""
    s = np.asarray(s, float)
    y = np.asarray(y, float)
    s0, s1 = float(s.min()), float(s.max())
    n_int = max(1, int(np.ceil((s1 - s0) / spacing - 1e-9)))
    h = max((s1 - s0) / n_int, 1e-9)
    m = n_int + 3
    A = design(s, s0, h, n_int)
    Aw = A if w is None else A * np.asarray(w, float)[:, None]
    AtA = Aw.T @ A
    lam = smoothing * np.trace(AtA) / m
    coef = np.linalg.solve(AtA + lam * subpixel._penalty(m), Aw.T @ y)
    return subpixel.UniformSpline(s0, h, n_int, coef)


class Fitter(subpixel._Fitter):
    """``recon.subpixel._Fitter`` from dense design matrices."""

    def __init__(self, s: np.ndarray, spacing: float, smoothing: float = 1e-4):
        super().__init__(s, spacing, smoothing)
        self.A = design(s, self.s0, self.h, self.n_int)
        self.dA = design(s, self.s0, self.h, self.n_int, 1)

    def fit(self, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Penalized least-squares coefficients of the rows ``ok`` of ``y``."""
        A = self.A[ok]
        AtA = A.T @ A
        lam = self.smoothing * np.trace(AtA) / AtA.shape[0]
        return np.linalg.solve(AtA + lam * self.P, A.T @ y[ok])

    def robust(self, y, ok, min_px, n_sigma):
        """Fit, reject points off the fit by more than max(n_sigma MAD, min_px), refit."""
        coef = self.fit(y, ok)
        r = y - self.A @ coef
        res = np.hypot(r[:, 0], r[:, 1])
        mad = 1.4826 * float(np.median(res[ok])) + 1e-3
        new_ok = ok & (res < max(n_sigma * mad, min_px))
        if new_ok.sum() != ok.sum() and new_ok.sum() >= 4:
            coef = self.fit(y, new_ok)
        return coef, new_ok

    def values(self, coef) -> np.ndarray:
        """The fit at every ``s``."""
        return self.A @ coef

    def derivatives(self, coef) -> np.ndarray:
        """The fit's derivative at every ``s``."""
        return self.dA @ coef


# ----------------------------------------------------------------------------- tip, following
def bilinear_diff(model, frame: np.ndarray, coeff: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Background difference at sub-pixel points (m, 2) px by bilinear interpolation; NaN outside."""
    H, W = model.shape
    u, v = pts[:, 0], pts[:, 1]
    inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    u = np.clip(u, 0, W - 1.001)
    v = np.clip(v, 0, H - 1.001)
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    fu = (u - u0).astype(np.float32)
    fv = (v - v0).astype(np.float32)
    out = np.zeros(len(pts), np.float32)
    fr = frame.reshape(-1)
    for du, dv, wt in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        idx = (v0 + dv) * W + (u0 + du)
        out += wt * (fr[idx].astype(np.float32) - model.stack[idx] @ coeff)
    out[~inside] = np.nan
    return out


def tip_along_axis(model, frame, coeff, p_end, t_end, radius_px, threshold, back_px=8.0, ahead_px=20.0, step=0.5):
    """``recon.subpixel._tip_along_axis``: median silhouette end (px along the axis), NaN if none."""
    n = np.array([-t_end[1], t_end[0]])
    offsets = np.array([-0.45, -0.2, 0.0, 0.2, 0.45]) * radius_px
    ts = np.arange(-back_px, ahead_px + 1e-9, step)
    pts = p_end[None, None, :] + ts[None, :, None] * t_end[None, None, :] + offsets[:, None, None] * n[None, None, :]
    d = bilinear_diff(model, frame, coeff, pts.reshape(-1, 2)).reshape(len(offsets), len(ts))
    n_in = int(round(2.0 / step))  # ~2 px inside the end: taken as fully covered
    L, T = d.shape
    ok = np.isfinite(d).all(axis=1)
    d = np.where(np.isfinite(d), d, 0.0)
    a = np.abs(d) > threshold
    last = T - 1 - np.argmax(a[:, ::-1], axis=1)
    j0 = last - n_in
    ok &= a.any(axis=1) & (j0 >= 2) & (last <= T - 4)
    j0 = np.where(ok, j0, 2)
    rows = np.arange(L)[:, None]
    ok &= np.cumsum(a, axis=1)[np.arange(L), j0] > 0.7 * (j0 + 1)
    sgn = np.sign(d[np.arange(L), np.where(ok, last, 0)])
    inside = d[rows, j0[:, None] - 2 + np.arange(n_in + 3)] * sgn[:, None]
    ref = np.max(inside, axis=1)
    ok &= ref > threshold
    if not ok.any():
        return np.nan
    cov = np.clip(d[rows, np.minimum(j0[:, None] + 1 + np.arange(n_in + 4), T - 1)] * (sgn / np.where(ok, ref, 1.0))[:, None], 0.0, 1.0)
    ends = ts[j0] + 0.5 * step + step * cov.sum(axis=1)
    return float(np.median(ends[ok]))


def near(points_px, visited_px, radius_px: float) -> np.ndarray:
    """``recon.subpixel._near``: which of ``points_px`` (n, 2) lie within ``radius_px`` of one of ``visited_px``."""
    if len(visited_px) == 0 or len(points_px) == 0:
        return np.zeros(len(points_px), bool)
    d2 = ((np.asarray(points_px)[:, None, :] - np.asarray(visited_px)[None, :, :]) ** 2).sum(axis=2)
    return d2.min(axis=1) < radius_px ** 2


def energy_hits(model, frame, coeff, seeds, t, half, nav, threshold, width_px, max_off):
    """``recon.subpixel._energy_hits``: ``(found (n,), centres (n, 2) px)`` of the tube's core on profiles."""
    tangents = np.ascontiguousarray(np.broadcast_to(t, seeds.shape), np.float64)
    major, minor = max(abs(t[0]), abs(t[1])), max(min(abs(t[0]), abs(t[1])), 1e-6)
    d = np.abs(gather_profiles(model, frame, coeff, seeds, tangents, half, min(int(nav), int(np.floor(major / minor + 1e-9))))[0])
    n, L = d.shape
    w = int(np.clip(np.rint(width_px), 2, L - 2))
    centres = np.rint(seeds).astype(np.float64)
    axis = 1 if abs(t[0]) >= abs(t[1]) else 0
    c = np.cumsum(np.pad(d, ((0, 0), (1, 0))), axis=1)
    mean = (c[:, w:] - c[:, :-w]) / w  # window j .. j + w - 1
    mid = np.arange(mean.shape[1]) + 0.5 * (w - 1) - half  # window centre's offset from the seed (px)
    mean = np.where(np.abs(mid)[None, :] <= np.asarray(max_off)[:, None], mean, -np.inf)
    j = np.argmax(mean, axis=1)
    level = np.median(d, axis=1)
    peak = mean[np.arange(n), j]
    found = (peak - level > 0.5 * threshold) & (peak > 2.0 * level)
    cols = np.clip(j[:, None] + np.arange(-1, w + 1), 0, L - 1)
    wt = d[np.arange(n)[:, None], cols]
    off = (wt * cols).sum(axis=1) / np.maximum(wt.sum(axis=1), 1e-9) - half
    centres[:, axis] += off
    return found, centres


# ----------------------------------------------------------------------------- 3D
def project(cam, P: np.ndarray):
    """``recon.fast._project``: :meth:`recon.camera.Camera.project` itself."""
    return cam.project(P)


def use_numpy_path(monkeypatch) -> None:
    """Swap every compiled kernel of the fast method for its oracle (undone when ``monkeypatch`` is)."""
    for name, oracle in (("frame_shift", frame_shift), ("frame_coefficients", frame_coefficients),
                         ("_coarse_foreground", coarse_foreground), ("_traced_path", traced_path),
                         ("edges_from_profiles", edges_from_profiles), ("_Fitter", Fitter),
                         ("_tip_along_axis", tip_along_axis), ("_near", near), ("_energy_hits", energy_hits)):
        monkeypatch.setattr(subpixel, name, oracle)
    monkeypatch.setattr(fast, "fit_curve", fit_curve)
    monkeypatch.setattr(fast, "_rays", fast._rays_in_python)
    monkeypatch.setattr(fast, "_project", project)
    monkeypatch.setattr(fast, "best_path", best_path)


# ----------------------------------------------------------------------------- guided search
def best_path(score: np.ndarray, points_mm: np.ndarray, step_mm: np.ndarray, start_mm: np.ndarray,
              stretch_cost: float = 1.0, max_stretch: float = 4.0):
    """:func:`recon.guided.best_path` (``recon._kernels.best_path_nb``): the path's candidate index per ray, or None."""
    K, n = score.shape
    d0 = np.linalg.norm(points_mm[0] - start_mm, axis=1)
    value = np.where(d0 <= max_stretch * step_mm[0] + 1e-9, score[0], -np.inf)
    back = np.zeros((K, n), np.int32)
    for k in range(1, K):
        step = np.linalg.norm(points_mm[k][:, None, :] - points_mm[k - 1][None, :, :], axis=2)  # (n now, n before)
        excess = step / max(step_mm[k], 1e-6) - 1.0
        total = value[None, :] - stretch_cost * np.maximum(excess, 0.0)
        total[excess > max_stretch - 1.0] = -np.inf
        back[k] = np.argmax(total, axis=1)
        value = score[k] + total[np.arange(n), back[k]]
    if not np.isfinite(value.max()):
        return None
    path = np.empty(K, np.int64)
    path[-1] = int(np.argmax(value))
    for k in range(K - 1, 0, -1):
        path[k - 1] = back[k, path[k]]
    return path


# ----------------------------------------------------------------------------- whole reconstructions
def compiled_and_oracle(monkeypatch, rig, backgrounds, frames):
    """``(compiled, oracle)``: each the views' centerlines and the pair's reconstruction, the second with every
    kernel swapped for its NumPy oracle (tests/fast_oracles.py)."""
    out = []
    for oracle in (False, True):
        if oracle:
            use_numpy_path(monkeypatch)
        model = fast.prepare_fast(rig, backgrounds)
        views = {n: subpixel.extract_view(model.views[n], frames[n], fast.FastParams().view) for n in model.pair}
        out.append((views, fast.FastReconstructor(model)(frames)))
    monkeypatch.undo()
    return out


def assert_agree(compiled, oracle):
    """The views' centres and ends within 1e-5 / 1e-3 px, the backbones within 1e-3 mm."""
    (views_a, ra), (views_b, rb) = compiled, oracle
    for name, va in views_a.items():
        vb = views_b[name]
        assert va.points_px.shape == vb.points_px.shape, name
        np.testing.assert_allclose(va.points_px, vb.points_px, atol=1e-5)
        np.testing.assert_allclose(va.end_px, vb.end_px, atol=1e-3)
        np.testing.assert_allclose(va.shift_px, vb.shift_px, atol=1e-3)
    assert backbone_errors(ra.points_world_mm, rb.points_world_mm)["max_error_mm"] < 1e-3
