"""Tests of twin.kinematics: bending-only and torsionally compliant CTR models."""
import time

import numpy as np
import pytest
from scipy.optimize import minimize

from twin import kinematics as kin
from twin.robot import Joints, Robot, Tube

OUTER = Tube("outer", 1.6, 1.2, 200.0, 30.0, 1 / 150)
INNER = Tube("inner", 1.0, 0.7, 260.0, 60.0, 1 / 60)


def robot(outer=OUTER, inner=INNER, T=None):
    return Robot((outer, inner)) if T is None else Robot((outer, inner), T)


def ei(t):
    return t.bending_stiffness_nmm2


def circumradius(a, b, c):
    ab, bc, ca = np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c)
    area2 = np.linalg.norm(np.cross(b - a, c - a))
    return ab * bc * ca / (2 * area2)


def section(bb, lo, hi):
    m = (bb.s_mm >= lo - 1e-9) & (bb.s_mm <= hi + 1e-9)
    return bb.p_world_mm[m]


def test_single_tube_is_exact_arc():
    k, rot = 1 / 40, 30.0
    tube = Tube("only", 1.0, 0.7, 100.0, 30.0, k)
    bb = kin.solve_bending(Robot((tube,)), Joints((50.0,), (rot,)))
    straight, arc = section(bb, 0, 20), section(bb, 20, 50)
    # Straight part on the z axis.
    np.testing.assert_allclose(straight[:, :2], 0, atol=1e-12)
    # Arc: every point 1/k from the centre, which lies towards the bending direction.
    d = np.array([np.cos(np.radians(rot)), np.sin(np.radians(rot)), 0.0])
    centre = np.array([0, 0, 20.0]) + d / k
    np.testing.assert_allclose(np.linalg.norm(arc - centre, axis=1), 1 / k, atol=1e-6)
    phi = k * 30
    tip = np.array([0, 0, 20.0]) + d * (1 - np.cos(phi)) / k + np.array([0, 0, 1.0]) * np.sin(phi) / k
    np.testing.assert_allclose(bb.tip_world_mm, tip, atol=1e-9)
    np.testing.assert_allclose(bb.R_world_body[-1][:, 2], d * np.sin(phi) + [0, 0, np.cos(phi)], atol=1e-9)


def test_aligned_tubes_stiffness_weighted_curvature():
    bb = kin.solve_bending(robot(), Joints((50.0, 50.0), (20.0, 20.0)))
    e1, e2 = ei(OUTER), ei(INNER)
    k1, k2 = OUTER.precurvature_per_mm, INNER.precurvature_per_mm
    for (lo, hi), k in [((0, 20), e2 * k2 / (e1 + e2)), ((20, 50), (e1 * k1 + e2 * k2) / (e1 + e2))]:
        p = section(bb, lo, hi)
        r = circumradius(p[0], p[len(p) // 2], p[-1])
        assert r == pytest.approx(1 / k, rel=1e-9)


def test_opposed_tubes_subtract_and_cancel():
    e1, e2 = ei(OUTER), ei(INNER)
    k1, k2 = OUTER.precurvature_per_mm, INNER.precurvature_per_mm
    bb = kin.solve_bending(robot(), Joints((50.0, 50.0), (0.0, 180.0)))
    p = section(bb, 20, 50)
    assert circumradius(p[0], p[len(p) // 2], p[-1]) == pytest.approx((e1 + e2) / abs(e1 * k1 - e2 * k2), rel=1e-9)
    # Inner precurvature chosen so that E I kappa matches: the overlap is straight.
    balanced = Tube("inner", 1.0, 0.7, 260.0, 60.0, e1 * k1 / e2)
    bb = kin.solve_bending(robot(inner=balanced), Joints((50.0, 50.0), (0.0, 180.0)))
    p = section(bb, 20, 50)
    chord = (p[-1] - p[0]) / np.linalg.norm(p[-1] - p[0])
    off = (p - p[0]) - np.outer((p - p[0]) @ chord, chord)
    assert np.abs(off).max() < 1e-9


@pytest.mark.parametrize("model", kin.MODELS)
def test_backbone_sampling_frames_and_tubes(model):
    j = Joints((50.0, 97.33), (10.0, 70.0))
    bb = kin.solve(robot(), j, model)
    s = bb.s_mm
    assert s[0] == 0 and s[-1] == 97.33 and np.diff(s).max() <= 0.1 + 1e-12 and np.diff(s).min() > 0
    assert 50.0 in s and 20.0 in s  # section boundaries are samples
    R = bb.R_world_body
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1, atol=1e-12)
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-15)
    # Chord direction = mean tangent up to O(h^2 kappa^2).
    chord = np.diff(bb.p_world_mm, axis=0) / np.diff(s)[:, None]
    np.testing.assert_allclose(chord, 0.5 * (R[1:, :, 2] + R[:-1, :, 2]), atol=1e-5)
    inside = s <= 50.0
    assert np.all(bb.outermost_tube[inside] == 0) and np.all(bb.outermost_tube[~inside] == 1)
    np.testing.assert_allclose(bb.outer_radius_mm, np.where(inside, 0.8, 0.5))


def test_inner_tube_retracted_is_hidden():
    bb = kin.solve_bending(robot(), Joints((50.0, 30.0), (0.0, 0.0)))
    assert bb.s_mm[-1] == 50.0 and np.all(bb.outermost_tube == 0)


@pytest.mark.parametrize("model", kin.MODELS)
def test_base_pose_moves_backbone_rigidly(model):
    j = Joints((50.0, 90.0), (0.0, 60.0))
    c, s = np.cos(0.7), np.sin(0.7)
    T = np.eye(4)
    T[:3, :3] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    T[:3, 3] = [10.0, -20.0, 300.0]
    a, b = kin.solve(robot(), j, model), kin.solve(robot(T=T), j, model)
    np.testing.assert_allclose(b.p_world_mm, a.p_world_mm @ T[:3, :3].T + T[:3, 3], atol=1e-9)
    np.testing.assert_allclose(b.R_world_body, T[:3, :3] @ a.R_world_body, atol=1e-12)


def test_compliant_approaches_bending_when_torsionally_stiff():
    j = Joints((50.0, 80.0), (0.0, 120.0))
    tip = kin.solve_bending(robot(), j).tip_world_mm
    err = [
        np.linalg.norm(kin.solve_compliant(robot(), j, torsion_scale=f).tip_world_mm - tip) for f in (1, 10, 100, 1e3, 1e4)
    ]
    assert err[0] > 1.0 and np.all(np.diff(err) < 0) and err[-1] < 0.05


@pytest.mark.parametrize("rot", [90.0, 150.0])
def test_torsional_windup_lags_rotation(rot):
    j = Joints((50.0, 80.0), (0.0, rot))
    tw = kin.solve_twist(robot(), j, [0.0, 50.0, 80.0])
    rel = tw.angle_deg[1, 1] - tw.angle_deg[0, 1]  # inner relative to outer at the outer tip
    assert 0 < rel < rot - 5
    assert 0 < tw.angle_deg[1, 2] < rot - 5  # inner tip lags its pin vise
    assert np.isnan(tw.angle_deg[0, 2]) and tw.torsion_per_mm[1, 2] == pytest.approx(0, abs=1e-7)
    d = np.linalg.norm(kin.solve_compliant(robot(), j).tip_world_mm - kin.solve_bending(robot(), j).tip_world_mm)
    assert d > 1.0


@pytest.mark.parametrize("rot", [0.0, 180.0])
def test_no_windup_when_symmetric(rot):
    j = Joints((50.0, 80.0), (30.0, 30.0 + rot))
    d = np.linalg.norm(kin.solve_compliant(robot(), j).tip_world_mm - kin.solve_bending(robot(), j).tip_world_mm)
    assert d < 1e-3


def test_compliant_twist_minimises_discrete_energy():
    """Independent check of the ODE and boundary-condition signs: minimise the
    discretised elastic energy of two fully overlapping curved tubes directly."""
    e, th = 40.0, np.radians([0.0, 120.0])
    outer = Tube("outer", 1.6, 1.2, 200.0, e, 1 / 100)
    inner = Tube("inner", 1.0, 0.7, 260.0, e, 1 / 40)
    r = robot(outer, inner)
    gj = np.array([outer.torsional_stiffness_nmm2, inner.torsional_stiffness_nmm2])
    hidden = np.array([outer.length_mm, inner.length_mm]) - e
    # Weighted-curvature bending energy per length is const - P cos(a1 - a2).
    P = ei(outer) * ei(inner) * outer.precurvature_per_mm * inner.precurvature_per_mm / (ei(outer) + ei(inner))
    n = 101
    h = e / (n - 1)
    w = np.full(n, h)
    w[[0, -1]] = h / 2

    def energy(x):
        a = x.reshape(2, n)
        da = np.diff(a, axis=1)
        E = (gj[:, None] * da**2).sum() / (2 * h) + (gj * (a[:, 0] - th) ** 2 / (2 * hidden)).sum()
        E -= P * (w * np.cos(a[0] - a[1])).sum()
        g = np.zeros_like(a)
        g[:, :-1] -= gj[:, None] * da / h
        g[:, 1:] += gj[:, None] * da / h
        g[:, 0] += gj * (a[:, 0] - th) / hidden
        gs = P * w * np.sin(a[0] - a[1])
        g[0] += gs
        g[1] -= gs
        return E, g.ravel()

    x0 = np.repeat(th, n)
    res = minimize(energy, x0, jac=True, method="L-BFGS-B", options={"maxiter": 20000, "gtol": 1e-12, "ftol": 1e-15})
    ref = np.degrees(res.x.reshape(2, n)[:, [0, -1]])
    tw = kin.solve_twist(r, Joints((e, e), np.degrees(th)), [0.0, e])
    assert abs(ref[1, 1] - 120) > 10  # a real wind-up, not a trivial case
    np.testing.assert_allclose(tw.angle_deg, ref, atol=0.01)


def test_bad_inputs():
    with pytest.raises(ValueError, match="2 tubes"):
        kin.solve_bending(robot(), Joints((50.0,), (0.0,)))
    with pytest.raises(ValueError, match="'inner'"):
        kin.solve_compliant(robot(), Joints((50.0, 300.0), (0.0, 0.0)))
    with pytest.raises(ValueError, match="'outer'"):
        kin.solve_bending(robot(), Joints((-1.0, 50.0), (0.0, 0.0)))
    with pytest.raises(ValueError, match="unknown kinematic model 'cosserat'"):
        kin.solve(robot(), Joints((50.0, 80.0), (0.0, 0.0)), "cosserat")


def test_compliant_reports_non_convergence(monkeypatch):
    monkeypatch.setattr(kin, "_RESIDUAL_TOL_PER_MM", 0.0)
    with pytest.raises(ValueError, match="compliant model did not converge"):
        kin.solve_compliant(robot(), Joints((50.0, 80.0), (0.0, 90.0)))


def test_nothing_extended():
    for model in kin.MODELS:
        bb = kin.solve(robot(), Joints((0.0, 0.0), (0.0, 45.0)), model)
        assert bb.s_mm.tolist() == [0.0] and np.allclose(bb.p_world_mm, 0)


def best_time(f, n=7):
    f()
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return min(t)


def test_speed():
    j = Joints((50.0, 100.0), (0.0, 90.0))
    # Budgets 5 ms / 300 ms; loose margins so a busy machine does not flake.
    assert best_time(lambda: kin.solve_bending(robot(), j)) < 10e-3
    assert best_time(lambda: kin.solve_compliant(robot(), j), 3) < 0.6
