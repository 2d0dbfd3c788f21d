"""Two-view geometry of the ``fast`` method: epipolar planes, correspondence of ordered curves, triangulation.

Every epipolar plane of a camera pair contains the baseline, so it is fixed by
one angle about it. :class:`EpipolarFrame` gives that angle ``phi`` for any
viewing ray of either camera; a 3D point seen by both cameras has the same
``phi`` in both. Two ordered centerlines therefore correspond where their
``phi`` agree, and each matched pair of rays is triangulated (closest points
of the two rays, which here lie in one plane).

Where a tube runs within an epipolar plane, ``phi`` hardly changes along it
and the match is ill-conditioned; :func:`conditioning` gives, per sample, the
sine of the angle between the curve and the epipolar line in the image, which
the caller uses to weight the triangulated points (the smoothing spline then
bridges such stretches). When ``phi`` is not monotonic along a curve (a tube
that turns back across epipolar planes), :func:`align_dp` matches the two
curves by dynamic programming under the ordering constraint (both curves run
base to tip), with a weak preference for proportional arc length that settles
stretches along an epipolar plane.

In the rig of ``scenes/paper.toml`` the baseline runs along world (0, 1, 1)
and the epipolar planes are nearly the planes x = const: a tube along the
insertion axis x crosses them at right angles (the best case); a tube bent
into a plane x = const would be the degenerate one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EpipolarFrame", "triangulate_rays", "conditioning", "align_dp", "monotonic"]


@dataclass(frozen=True, eq=False)
class EpipolarFrame:
    """The pencil of epipolar planes of two cameras.

    Attributes
    ----------
    center_a, center_b : (3,) arrays
        Optical centres (world, mm).
    baseline : (3,) unit vector from ``center_a`` to ``center_b``.
    e1, e2 : (3,) unit vectors
        Orthonormal with the baseline; ``phi = atan2(n.e2, n.e1)`` with
        ``n = baseline x ray`` (``phi = 0`` at ``reference_world_mm``).
    """

    center_a: np.ndarray
    center_b: np.ndarray
    baseline: np.ndarray
    e1: np.ndarray
    e2: np.ndarray

    @classmethod
    def from_cameras(cls, cam_a, cam_b, reference_world_mm) -> "EpipolarFrame":
        """The epipolar pencil of two cameras, ``phi = 0`` on the plane through ``reference_world_mm``.

        Parameters
        ----------
        cam_a, cam_b : recon.camera.Camera
            The two cameras; their optical centres (world frame, mm) fix the baseline.
        reference_world_mm : (3,) array_like
            A point (world frame, mm) whose epipolar plane gets ``phi = 0``, e.g. the robot
            base; on the baseline itself a fixed world axis is used instead.

        Returns
        -------
        EpipolarFrame

        Raises
        ------
        ValueError
            The cameras' optical centres coincide (closer than 1e-9 mm).
        """
        ca, cb = cam_a.center_world_mm, cam_b.center_world_mm
        b = cb - ca
        nb = np.linalg.norm(b)
        if nb < 1e-9:
            raise ValueError("epipolar geometry: the two cameras share their optical centre")
        b = b / nb
        n = np.cross(b, np.asarray(reference_world_mm, float) - ca)
        if np.linalg.norm(n) < 1e-9:
            n = np.cross(b, [1.0, 0.0, 0.0]) if abs(b[0]) < 0.9 else np.cross(b, [0.0, 1.0, 0.0])
        e1 = n / np.linalg.norm(n)
        e2 = np.cross(b, e1)
        return cls(ca, cb, b, e1, e2)

    def phi(self, directions: np.ndarray) -> np.ndarray:
        """Epipolar-plane angle (rad) of rays with world directions (n, 3).

        Parameters
        ----------
        directions : (n, 3) array
            Ray directions (world frame, any length) from either optical centre.

        Returns
        -------
        (n,) ndarray
            ``phi`` in ``(-pi, pi]`` (rad); equal for the two cameras' rays through one 3D point.
        """
        n = np.cross(self.baseline, directions)
        return np.arctan2(n @ self.e2, n @ self.e1)


def triangulate_rays(ca, da, cb, db):
    """Midpoints of the closest points of ray pairs ``ca + s da`` and ``cb + t db``.

    Parameters
    ----------
    ca, cb : (3,) arrays
        Ray origins.
    da, db : (n, 3) arrays
        Unit directions.

    Returns
    -------
    points : (n, 3)
    gap : (n,)
        Distance between the two rays at their closest points (mm).
    """
    w0 = ca - cb
    b = np.einsum("ij,ij->i", da, db)
    d = da @ w0
    e = db @ w0
    den = np.maximum(1.0 - b * b, 1e-12)
    s = (b * e - d) / den
    t = (e - b * d) / den
    pa = ca + s[:, None] * da
    pb = cb + t[:, None] * db
    return 0.5 * (pa + pb), np.linalg.norm(pa - pb, axis=1)


def conditioning(xy_norm: np.ndarray, epipole_h: np.ndarray) -> np.ndarray:
    """|sin| of the angle between an ordered curve and the epipolar lines, per sample.

    Parameters
    ----------
    xy_norm : (n, 2)
        Curve samples in ideal normalized coordinates of one camera.
    epipole_h : (3,)
        The other camera's centre in this camera's frame (homogeneous epipole).

    Returns
    -------
    (n,) ndarray
        ``|sin|`` of the angle in [0, 1]: 0 where the curve runs along its epipolar line
        (ill-conditioned match), 1 where it crosses it at right angles.
    """
    t = np.gradient(xy_norm, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-15)
    ex, ey, ez = epipole_h
    lx = ex - xy_norm[:, 0] * ez
    ly = ey - xy_norm[:, 1] * ez
    ln = np.maximum(np.hypot(lx, ly), 1e-15)
    return np.abs(t[:, 0] * ly - t[:, 1] * lx) / ln


def monotonic(phi: np.ndarray, tolerance: float) -> int:
    """+1 or -1 when ``phi`` runs one way (backsteps up to ``tolerance`` allowed), 0 otherwise.

    Parameters
    ----------
    phi : (n,) array
        Epipolar angles along an ordered curve (rad).
    tolerance : float
        Largest step back from the running extreme still counted as monotonic (rad).

    Returns
    -------
    int
        +1 (increasing from first to last), -1 (decreasing), or 0 (turns back, or fewer than 2 samples).
    """
    if phi.size < 2:
        return 0
    direction = 1 if phi[-1] >= phi[0] else -1
    run = np.maximum.accumulate(direction * phi)
    return direction if float(np.max(run - direction * phi)) <= tolerance else 0


def align_dp(phi_a, phi_b, frac_a, frac_b, phi_scale: float, frac_weight: float = 0.05):
    """Monotone alignment of two ordered curves by their epipolar angles.

    Minimizes the sum over the matched pairs of
    ``((phi_a - phi_b) / phi_scale)^2 + frac_weight * (frac_a - frac_b)^2 * n``
    (``frac`` = fraction of each curve's length, a weak prior that resolves
    stretches lying in one epipolar plane), over paths from (0, 0) to the last samples of both that advance in one
    or both curves at each step.

    Parameters
    ----------
    phi_a, phi_b : (na,), (nb,) arrays
        Epipolar angles along each ordered curve, base to tip (rad).
    frac_a, frac_b : (na,), (nb,) arrays
        Fraction of each curve's arc length at its samples (0 to 1).
    phi_scale : float
        Angle difference counted as one unit of cost (rad); must be > 0.
    frac_weight : float
        Weight of the arc-length prior, multiplied by ``n = max(na, nb)``.

    Returns
    -------
    (ia, ib) : int arrays
        Matched sample indices, in order.
    """
    na, nb = len(phi_a), len(phi_b)
    C = ((phi_a[:, None] - phi_b[None, :]) / phi_scale) ** 2 + frac_weight * max(na, nb) * (frac_a[:, None] - frac_b[None, :]) ** 2
    D = np.empty_like(C)
    D[0] = np.cumsum(C[0])
    for i in range(1, na):
        prev = D[i - 1]
        # from (i-1, j) or (i-1, j-1)
        m = prev.copy()
        m[1:] = np.minimum(prev[1:], prev[:-1])
        # then any number of steps along j: D[i, j] = min_k<=j (m[k] + sum C[i, k..j])
        P = np.cumsum(C[i])
        Pm = np.concatenate([[0.0], P[:-1]])
        D[i] = P + np.minimum.accumulate(m - Pm)
    i, j = na - 1, nb - 1
    ia, ib = [i], [j]
    while i > 0 or j > 0:
        cands = []
        if i > 0 and j > 0:
            cands.append((D[i - 1, j - 1], i - 1, j - 1))
        if i > 0:
            cands.append((D[i - 1, j], i - 1, j))
        if j > 0:
            cands.append((D[i, j - 1], i, j - 1))
        _, i, j = min(cands)
        ia.append(i)
        ib.append(j)
    return np.asarray(ia[::-1]), np.asarray(ib[::-1])
