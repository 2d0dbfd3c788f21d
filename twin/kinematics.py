"""Kinematic models of a concentric tube robot: backbone shape from joint values.

Two models, both without external load:

* ``solve_bending``: bending only (torsionally rigid tubes). Each tube's
  material frame keeps its pin vise rotation along the whole backbone, so the
  backbone is a chain of constant-curvature arcs, integrated in closed form.
* ``solve_compliant``: torsionally compliant model of Rucker, Webster et al.
  (IJRR 2010) / Dupont et al. (T-RO 2010). The tubes twist along their length
  (and along their straight transmissions inside the actuation unit); the twist
  angles solve a boundary-value problem, solved by shooting.

Frames
------
The body frames are the torsion-free (Bishop, parallel-transported) frame of
the backbone: at s = 0 it is the base frame, and it obeys dR/ds = R [u]x with
body curvature u = (u_x, u_y, 0). Tube i's material frame is the body frame
rotated about z by its twist angle alpha_i(s); in the bending model
alpha_i = rotation_deg[i] everywhere. A tube with precurvature kappa at angle
alpha bends the backbone towards (cos alpha, sin alpha, 0), i.e. its curvature
vector is kappa (-sin alpha, cos alpha, 0) (x_b is the bending direction at
rotation 0).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

from twin.robot import Backbone, Joints, Robot

__all__ = ["solve_bending", "solve_compliant", "solve_twist", "solve", "Twist", "MODELS"]

MODELS = ("bending", "compliant")

# Shooting converged when every tube's distal torsion is below this (1/mm):
# a residual torsion of 1e-7 /mm twists a tube by < 1e-5 rad over 100 mm.
_RESIDUAL_TOL_PER_MM = 1e-7


class Twist(NamedTuple):
    """Twist state of the tubes along the backbone (compliant model).

    Attributes
    ----------
    s_mm : (m,) array
        Arc lengths (mm).
    angle_deg : (n_tubes, m) array
        Angle of tube i's material frame about the backbone tangent, relative
        to the torsion-free body frame (deg); NaN where tube i is absent
        (s > extension_mm[i]). Equals rotation_deg[i] in the bending model.
    torsion_per_mm : (n_tubes, m) array
        Torsional curvature u_iz = d(angle)/ds (rad/mm); NaN where absent.
    """

    s_mm: np.ndarray
    angle_deg: np.ndarray
    torsion_per_mm: np.ndarray


class _Sections(NamedTuple):
    """The backbone split where the set of present/curved tubes changes."""

    bounds: np.ndarray   # (k+1,) section boundaries (mm), 0 .. max extension
    present: np.ndarray  # (k, n) bool: tube i exposed in section j
    kappa: np.ndarray    # (k, n) precurvature of tube i in section j (1/mm), 0 if straight/absent
    weight: np.ndarray   # (k, n) E_i I_i / sum of E I over present tubes


def _sections(robot: Robot, joints: Joints) -> _Sections:
    ext = np.asarray(joints.extension_mm)
    curved = np.array([t.curved_length_mm for t in robot.tubes])
    kappa = np.array([t.precurvature_per_mm for t in robot.tubes])
    ei = np.array([t.bending_stiffness_nmm2 for t in robot.tubes])
    length = ext.max()
    cuts = np.concatenate([[0.0, length], ext, np.clip(ext - curved, 0.0, None)])
    bounds = np.unique(cuts[cuts <= length])
    if len(bounds) == 1:  # nothing exposed: a single point, no section
        bounds = bounds[:1]
    mid = 0.5 * (bounds[:-1] + bounds[1:])[:, None]
    # Section-wise constant: decide membership at the section midpoint.
    present = ext[None, :] > mid
    sec_kappa = np.where(present & (mid > ext - curved), kappa, 0.0)
    ei_present = np.where(present, ei, 0.0)
    weight = ei_present / ei_present.sum(axis=1, keepdims=True)
    return _Sections(bounds, present, sec_kappa, weight)


def _grid(bounds: np.ndarray, ds_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc-length samples with every section boundary on the grid.

    Returns ``s`` (m,) and the section index of each of the m-1 intervals.
    Each section gets equal intervals of at most ``ds_mm``.
    """
    if not ds_mm > 0:
        raise ValueError(f"ds_mm must be > 0, got {ds_mm}")
    lens = np.diff(bounds)
    counts = np.maximum(1, np.ceil(lens / ds_mm - 1e-9)).astype(int)
    section = np.repeat(np.arange(len(lens)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    frac = (np.arange(counts.sum()) - first) / counts[section]
    s = np.append(bounds[section] + frac * lens[section], bounds[-1])
    return s, section


def _curvature(weight: np.ndarray, kappa: np.ndarray, alpha_rad: np.ndarray) -> np.ndarray:
    """Backbone body curvature (…, 2) from tube angles: stiffness-weighted sum
    of the precurvature vectors kappa_i (-sin alpha_i, cos alpha_i)."""
    wk = weight * kappa
    return np.stack([-(wk * np.sin(alpha_rad)).sum(-1), (wk * np.cos(alpha_rad)).sum(-1)], axis=-1)


def _arcs(u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Rigid transforms (k, 4, 4) across arcs of constant body curvature.

    ``u`` (k, 2) is the body curvature (u_x, u_y) (1/mm), ``h`` (k,) the arc
    lengths (mm). Exact: R = expm([u]x h) (Rodrigues) and the translation is
    the closed-form integral of the tangent, so no discretisation error.
    """
    ux, uy = u[:, 0], u[:, 1]
    th = np.hypot(ux, uy) * h
    # sin(k h)/k and (1 - cos(k h))/k^2 written with sinc: exact and finite at k = 0.
    a = h * np.sinc(th / np.pi)
    b = 0.5 * h**2 * np.sinc(th / (2 * np.pi)) ** 2
    T = np.zeros((len(h), 4, 4))
    # R = I + a [u]x + b [u]x^2 with [u]x^2 = u u^T - |u|^2 I (u_z = 0).
    T[:, 0, 0] = 1 - b * uy**2
    T[:, 1, 1] = 1 - b * ux**2
    T[:, 2, 2] = 1 - b * (ux**2 + uy**2)
    T[:, 0, 1] = T[:, 1, 0] = b * ux * uy
    T[:, 0, 2], T[:, 2, 0] = a * uy, -a * uy
    T[:, 1, 2], T[:, 2, 1] = -a * ux, a * ux
    T[:, :3, 3] = np.stack([b * uy, -b * ux, a], -1)  # integral of the tangent over the arc
    T[:, 3, 3] = 1.0
    return T


def _backbone(robot: Robot, joints: Joints, s: np.ndarray, T: np.ndarray) -> Backbone:
    """Backbone from base-frame body poses ``T`` (m, 4, 4) at arc lengths ``s``."""
    Rwb, twb = robot.T_world_base[:3, :3], robot.T_world_base[:3, 3]
    ext = np.asarray(joints.extension_mm)
    # Tubes are outermost first, so the first one still reaching s is outermost.
    outermost = np.argmax(ext[None, :] >= s[:, None], axis=1)
    radius = np.array([t.outer_radius_mm for t in robot.tubes])[outermost]
    return Backbone(
        s_mm=s,
        p_world_mm=T[:, :3, 3] @ Rwb.T + twb,
        R_world_body=Rwb @ T[:, :3, :3],
        outer_radius_mm=radius,
        outermost_tube=outermost,
    )


def solve_bending(robot: Robot, joints: Joints, ds_mm: float = 0.1) -> Backbone:
    """Backbone of the bending-only (torsionally rigid) model.

    Every tube keeps its pin vise rotation along its length; in each section
    (split at tube ends and at starts of precurvature) the backbone curvature
    is the stiffness-weighted sum of the precurvatures of the tubes present
    (straight tubes count in the stiffness), giving a constant-curvature arc.

    Parameters
    ----------
    robot : Robot
        Tubes (outermost first) and base pose ``T_world_base`` (mm).
    joints : Joints
        Extensions (mm) and pin vise rotations about z_b (deg).
    ds_mm : float
        Maximum arc-length spacing of the samples (mm).

    Returns
    -------
    Backbone
        Samples from s = 0 to max(extension_mm), every section boundary
        included; positions (mm) and body frames (z = tangent, torsion-free,
        equal to the base frame at s = 0) in the world frame.

    Raises
    ------
    ValueError
        If the joints do not fit the robot.
    """
    joints.check(robot)
    sec = _sections(robot, joints)
    s, section = _grid(sec.bounds, ds_mm)
    alpha = np.deg2rad(np.asarray(joints.rotation_deg))
    u = _curvature(sec.weight, sec.kappa, alpha)
    # Chain the few section arcs, then place every sample on its section's arc.
    starts = [np.eye(4)]
    for Tj in _arcs(u, np.diff(sec.bounds)):
        starts.append(starts[-1] @ Tj)
    at = np.append(section, section[-1:])  # the tip closes the last section
    T = np.asarray(starts)[at] @ _arcs(u[at], s - sec.bounds[at]) if len(section) else np.eye(4)[None]
    return _backbone(robot, joints, s, T)


def _twist_problem(robot: Robot, joints: Joints, torsion_scale: float):
    """Right-hand side and initial state of the twist ODE.

    State y = [alpha (n), u_z (n)] and, with sensitivities, the n x n
    derivatives of both with respect to the unknown initial torsions.
    From the energy sum_i int 1/2 EI_i |u - R(alpha_i) u*_i|^2 + 1/2 GJ_i alpha_i'^2,
    with u the weighted curvature, the Euler-Lagrange equation reads
    u_iz' = (EI_i/GJ_i) kappa_i sum_j w_j kappa_j sin(alpha_i - alpha_j)
    (= (EI/GJ)(u_ix u*_iy - u_iy u*_ix) in tube i's frame).
    Absent tubes are frozen, so the final u_z equals each tube's distal torsion.
    """
    n = robot.n_tubes
    ei = np.array([t.bending_stiffness_nmm2 for t in robot.tubes])
    gj = torsion_scale * np.array([t.torsional_stiffness_nmm2 for t in robot.tubes])
    c = ei / gj

    def rhs(_s, y, present, kappa, weight, sens):
        alpha, uz = y[:n], y[n : 2 * n]
        diff = alpha[:, None] - alpha[None, :]
        wk, bk = weight * kappa, c * kappa
        out = [np.where(present, uz, 0.0), bk * (np.sin(diff) @ wk)]
        if sens:
            s_alpha = y[2 * n : 2 * n + n * n].reshape(n, n)
            s_uz = y[2 * n + n * n :].reshape(n, n)
            cw = np.cos(diff) * wk[None, :]
            jac = -bk[:, None] * cw  # d(u_z')/d(alpha)
            jac[np.diag_indices(n)] += bk * cw.sum(1)
            out += [(np.where(present[:, None], s_uz, 0.0)).ravel(), (jac @ s_alpha).ravel()]
        return np.concatenate(out)

    # Pin vise at s = extension - length < 0 sets the angle; the straight
    # transmission carries the constant torsion u_z(0), hence
    # alpha(0) = rotation + (length - extension) u_z(0) (Dupont 2010, beta_i < 0).
    rot = np.deg2rad(np.asarray(joints.rotation_deg))
    hidden = np.array([t.length_mm for t in robot.tubes]) - np.asarray(joints.extension_mm)

    def y0(uz0, sens):
        y = [rot + hidden * uz0, uz0]
        if sens:
            y += [np.diag(hidden).ravel(), np.eye(n).ravel()]
        return np.concatenate(y)

    return rhs, y0


def _integrate_twist(rhs, y, sec: _Sections, rtol: float, sens: bool, s_eval=None):
    """Integrate section by section; return the final state and, if
    ``s_eval`` (sorted) is given, the states at those arc lengths (cols)."""
    at = []
    for j in range(len(sec.bounds) - 1):
        lo, hi = sec.bounds[j], sec.bounds[j + 1]
        t_eval = None
        if s_eval is not None:
            last = j == len(sec.bounds) - 2
            q = s_eval[(s_eval >= lo) & ((s_eval < hi) | last)]
            t_eval = np.append(q[q < hi], hi)  # strictly increasing, ends at hi
        args = (sec.present[j], sec.kappa[j], sec.weight[j], sens)
        if np.count_nonzero(sec.kappa[j]) < 2:
            # Fewer than two curved tubes: no torque coupling, torsions are
            # constant and angles linear, so step exactly (and fast).
            rate = rhs(lo, y, *args)
            ys = y[:, None] + rate[:, None] * ((hi if t_eval is None else t_eval) - lo)
        else:
            sol = solve_ivp(rhs, (lo, hi), y, method="DOP853", rtol=rtol, atol=1e-3 * rtol, t_eval=t_eval, args=args)
            if not sol.success:
                raise ValueError(f"compliant model did not converge: integration failed at s={sol.t[-1]:.3f} mm: {sol.message}")
            ys = sol.y
        y = ys[:, -1]
        if s_eval is not None:
            at.append(ys[:, np.searchsorted(t_eval, q)])
    return y, (np.concatenate(at, axis=1) if at else np.empty((len(y), 0)))


def _twist_states(robot, joints, sec, s_eval, rtol, torsion_scale):
    """Shoot on the initial torsions u_z(0) so that every distal end is
    torque free (u_iz(extension_i) = 0); return alpha, u_z at ``s_eval``."""
    n = robot.n_tubes
    rhs, y0 = _twist_problem(robot, joints, torsion_scale)

    def residual(uz0):
        y, _ = _integrate_twist(rhs, y0(uz0, True), sec, rtol, True)
        return y[n : 2 * n], y[2 * n + n * n :].reshape(n, n)

    # Warm start: the bending-only solution (no twist).
    sol = root(residual, np.zeros(n), jac=True, method="hybr", options={"xtol": 1e-12})
    res = residual(sol.x)[0]
    if not np.all(np.abs(res) < _RESIDUAL_TOL_PER_MM):
        raise ValueError(
            f"compliant model did not converge: distal torsions {res} 1/mm after shooting ({sol.message})"
        )
    _, y = _integrate_twist(rhs, y0(sol.x, False), sec, rtol, False, s_eval)
    return y[:n], y[n:]


def solve_compliant(
    robot: Robot, joints: Joints, ds_mm: float = 0.1, rtol: float = 1e-8, *, torsion_scale: float = 1.0
) -> Backbone:
    """Backbone of the torsionally compliant model (no external load).

    The tube twist angles alpha_i(s) solve the torsion boundary-value problem
    (torque-free distal ends, pin vise angles imposed through the straight
    transmissions); the backbone curvature is the stiffness-weighted sum of
    the tubes' rotated precurvatures, integrated with the exponential midpoint
    rule on each sample interval (section boundaries are samples).

    Parameters
    ----------
    robot : Robot
        Tubes (outermost first) and base pose ``T_world_base`` (mm).
    joints : Joints
        Extensions (mm) and pin vise rotations about z_b (deg).
    ds_mm : float
        Maximum arc-length spacing of the samples (mm).
    rtol : float
        Relative tolerance of the twist ODE integration.
    torsion_scale : float
        Multiplies every tube's torsional stiffness G J (for studies; large
        values approach the bending-only model).

    Returns
    -------
    Backbone
        As ``solve_bending``; body frames are the torsion-free frame of the
        backbone (not any tube's material frame; see ``solve_twist``).

    Raises
    ------
    ValueError
        If the joints do not fit the robot, or "compliant model did not
        converge: ..." if the shooting fails (e.g. near a snapping instability).
    """
    joints.check(robot)
    sec = _sections(robot, joints)
    s, section = _grid(sec.bounds, ds_mm)
    mid = 0.5 * (s[:-1] + s[1:])
    alpha, _ = _twist_states(robot, joints, sec, mid, rtol, torsion_scale)
    u = _curvature(sec.weight[section], sec.kappa[section], alpha.T)
    # Exponential midpoint rule (local error O(h^3) but the curvature varies
    # slowly; sections start on samples, so curvature jumps are exact).
    T = _arcs(u, np.diff(s))
    d = 1  # prefix product T_0 T_1 ... T_k by doubling: log2(m) batched matmuls, not an m-step loop
    while d < len(T):
        T[d:] = T[:-d] @ T[d:]
        d *= 2
    return _backbone(robot, joints, s, np.concatenate([np.eye(4)[None], T]))


def solve_twist(
    robot: Robot, joints: Joints, s_mm=None, rtol: float = 1e-8, *, torsion_scale: float = 1.0
) -> Twist:
    """Twist angles and torsions of the tubes in the compliant model.

    Parameters
    ----------
    robot, joints, rtol, torsion_scale
        As ``solve_compliant``.
    s_mm : array_like, optional
        Arc lengths (mm) in [0, max(extension_mm)]; default: the backbone grid
        with 0.1 mm spacing.

    Returns
    -------
    Twist
        Angles (deg) relative to the torsion-free body frame of the backbone
        and torsions (1/mm), NaN where a tube is absent.
    """
    joints.check(robot)
    sec = _sections(robot, joints)
    s = _grid(sec.bounds, 0.1)[0] if s_mm is None else np.asarray(s_mm, dtype=np.float64)
    order = np.argsort(s)
    if len(s) and (s[order[0]] < 0 or s[order[-1]] > sec.bounds[-1]):
        raise ValueError(f"s_mm must lie in [0, {sec.bounds[-1]}] mm")
    alpha, uz = np.full((2, robot.n_tubes, len(s)), np.nan)
    if len(sec.bounds) > 1:
        a, t = _twist_states(robot, joints, sec, s[order], rtol, torsion_scale)
        alpha[:, order], uz[:, order] = a, t
    absent = np.asarray(joints.extension_mm)[:, None] < s[None, :]
    alpha[absent] = uz[absent] = np.nan
    return Twist(s, np.rad2deg(alpha), uz)


def solve(robot: Robot, joints: Joints, model: str, ds_mm: float = 0.1) -> Backbone:
    """Backbone from the named kinematic model.

    Parameters
    ----------
    robot, joints, ds_mm
        As ``solve_bending``.
    model : str
        "bending" (torsionally rigid) or "compliant" (torsionally compliant).

    Raises
    ------
    ValueError
        For an unknown model name, or as the chosen solver.
    """
    if model == "bending":
        return solve_bending(robot, joints, ds_mm)
    if model == "compliant":
        return solve_compliant(robot, joints, ds_mm)
    raise ValueError(f"unknown kinematic model {model!r}; expected one of {MODELS}")
