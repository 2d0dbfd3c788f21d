"""Verify and calibrate kinematic models of a concentric tube robot against measured backbones.

This is what the rig is for (Morimoto & Sketch): kinematic models predict the
backbone only to several millimetres, and robots of new materials (3D-printed
plastic tubes) have poorly known properties. Measured backbones (reconstructions,
or the twin's ground truth) and the joint values recorded with them let us

* **verify** a model: per frame, the tip error, the mean shape error (closest
  point, both directions) and the error along the arc length of the model's
  prediction against the measurement (:func:`verify`);
* **calibrate** it: estimate robot parameters (precurvatures, stiffness ratios,
  actuator offsets, the base pose) by nonlinear least squares over all frames,
  with 95 % confidence intervals (:func:`fit`).

Residuals
---------
A measured backbone is a polyline ``q_k`` (base first, world mm) that may miss
its first millimetres (a reconstruction often starts some way out of the
actuation unit). Its points get arc lengths ``s_k = s0 + c_k`` where ``c_k`` is
the cumulative length along the measured polyline and ``s0`` (where the
measurement starts on the robot) is the mean of ``sigma_k - c_k`` over the first
half of its points, ``sigma_k`` being the arc length of the model point closest to
``q_k``; ``c_k`` is measured along a lightly smoothed copy of the polyline, as
summing noisy segments overestimates length. The
residuals of a frame are the vectors ``q_k - p(s_k)`` (``p`` the model backbone,
continued straight past its ends) and ``w_tip (q_last - p_tip)``.

Identifiability
---------------
Without external loads the shape depends on the tubes' bending stiffnesses
``E I`` only through their ratios (and, in the compliant model, on ``E I / G J``
= ``1 + nu``), so absolute Young's moduli cannot be estimated from shapes:
fit ``stiffness_ratio`` (or one tube's ``youngs_modulus_gpa`` with the others
fixed, which is the same thing). A rotation of the base about its insertion axis
is the same as the same rotation offset on every tube.

Parameters (``fit`` names)
--------------------------
``<tube>.precurvature_per_mm``, ``<tube>.curved_length_mm``, ``<tube>.length_mm``
(compliant: the straight transmission twists), ``<tube>.youngs_modulus_gpa``,
``<tube>.poisson_ratio`` (compliant only), ``stiffness_ratio`` (two tubes: E I of
the inner over the outer) or ``stiffness_ratio.<tube>`` (E I of that tube over
the outermost's), ``rotation_offset_deg.<tube>``, ``insertion_offset_mm.<tube>``
(the true joint is the recorded one plus the offset), ``base.position_mm``
(three values, world), ``base.rotation_deg`` (three values: a rotation vector
about the base's own x, y, z axes applied to the nominal base orientation).
``<tube>`` is a tube name or its index (0 = outermost).

Units: mm, 1/mm, deg, GPa. Robot files: a TOML ``[robot]`` table exactly as in a
scene (see docs/scenes.md), optionally with ``[actuator]`` joint offsets; :mod:`twin.robotfile`
reads and writes them (here as a :class:`ModelState`: :func:`load_robot_file`, :func:`robot_to_toml`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from recon.geometry import arc_length, closest_arc_length, interp_rows, resample_polyline, rotation_from_rotvec
from recon.metrics import point_to_polyline_distances

from . import robotfile
from .kinematics import MODELS, solve
from .robot import Backbone, Joints, Robot, Tube
from .schema import SceneError

__all__ = [
    "ModelFitError",
    "JointOffsets",
    "ModelState",
    "Frame",
    "load_robot_file",
    "robot_from_dict",
    "robot_to_toml",
    "predict",
    "compare",
    "verify",
    "aggregate",
    "along_profile",
    "parse_params",
    "fit",
    "FitResult",
    "split_holdout",
    "LOSSES",
]

LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


class ModelFitError(ValueError):
    """A verification or fit that cannot be done; the message is one line."""


# ----------------------------------------------------------------------------- model state
@dataclass(frozen=True, eq=False)
class JointOffsets:
    """Actuator calibration: true joint = recorded joint + offset (per tube, outermost first)."""

    extension_mm: np.ndarray
    rotation_deg: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> "JointOffsets":
        return cls(np.zeros(n), np.zeros(n))

    def apply(self, joints: Joints) -> Joints:
        return Joints(
            extension_mm=tuple(np.asarray(joints.extension_mm) + self.extension_mm),
            rotation_deg=tuple(np.asarray(joints.rotation_deg) + self.rotation_deg),
        )

    @property
    def is_zero(self) -> bool:
        return not (np.any(self.extension_mm) or np.any(self.rotation_deg))


@dataclass(frozen=True, eq=False)
class ModelState:
    """What predicts a backbone from recorded joints: robot, model name, joint offsets."""

    robot: Robot
    model: str
    offsets: JointOffsets = None

    def __post_init__(self):
        if self.model not in MODELS:
            raise ModelFitError(f"unknown kinematic model {self.model!r}; expected one of {', '.join(MODELS)}")
        if self.offsets is None:
            object.__setattr__(self, "offsets", JointOffsets.zeros(self.robot.n_tubes))


@dataclass(frozen=True, eq=False)
class Frame:
    """One measurement: recorded joints and the measured backbone (world mm, base first)."""

    index: int
    joints: Joints
    points_mm: np.ndarray


# ----------------------------------------------------------------------------- robot files
def robot_from_dict(d: dict, source: str = "session.json") -> tuple:
    """``(Robot, model)`` from session.json's ``robot`` (:func:`twin.robotfile.robot_from_dict`); ModelFitError if invalid."""
    return robotfile.robot_from_dict(d, source, ModelFitError)


def load_robot_file(path) -> ModelState:
    """The :class:`ModelState` of a robot file (:func:`twin.robotfile.read_robot_file`).

    A TOML ``[robot]`` table as in a scene (+ ``[[robot.tubes]]``), an optional
    ``[actuator]`` table with ``rotation_offset_deg`` and ``insertion_offset_mm`` (lists,
    one per tube: true joint = recorded + offset), and ``[fit]`` (what
    :func:`robot_to_toml` writes about a fit; not read). Errors (ModelFitError) name the
    file and the key.
    """
    try:
        rf = robotfile.read_robot_file(path)
    except SceneError as exc:
        raise ModelFitError(str(exc)) from None
    return ModelState(rf.robot, rf.model, JointOffsets(rf.insertion_offset_mm, rf.rotation_offset_deg))


def robot_to_toml(state: ModelState, header: str = "", fit_table: dict | None = None) -> str:
    """A robot file (TOML) for ``state`` (:func:`twin.robotfile.robot_file_toml`); :func:`load_robot_file` reads it back.

    The ``[robot]`` table (with its ``[[robot.tubes]]``) is a scene's robot
    table: copy it into a scene to render the twin with this robot.
    ``[actuator]`` holds the joint offsets (true = recorded + offset), and
    ``[fit]`` (optional) what the fit found, for the record.
    """
    return robotfile.robot_file_toml(state.robot, state.model, state.offsets.extension_mm, state.offsets.rotation_deg,
                                     header, fit_table)


# ----------------------------------------------------------------------------- prediction and comparison
def predict(state: ModelState, joints: Joints, ds_mm: float = 0.25) -> Backbone:
    """Model backbone for recorded ``joints`` (offsets applied); ValueError if the model fails."""
    return solve(state.robot, state.offsets.apply(joints), state.model, ds_mm)


def _at(bb: Backbone, s: np.ndarray) -> np.ndarray:
    """Model positions at arc lengths ``s``, continued straight past both ends."""
    p, sm = bb.p_world_mm, bb.s_mm
    sc = np.clip(s, sm[0], sm[-1])
    out = interp_rows(sc, sm, p)
    lo, hi = s < sm[0], s > sm[-1]
    if lo.any():
        out[lo] += (s[lo] - sm[0])[:, None] * bb.R_world_body[0][:, 2]
    if hi.any():
        out[hi] += (s[hi] - sm[-1])[:, None] * bb.R_world_body[-1][:, 2]
    return out


def _smooth(points: np.ndarray, raw: np.ndarray, h_mm: float) -> np.ndarray:
    """Local linear (Gaussian-weighted, bandwidth ``h_mm`` of polyline length) smoothing of a polyline."""
    d = raw[None, :] - raw[:, None]
    w = np.exp(-0.5 * (d / h_mm) ** 2)
    s0, s1, s2 = w.sum(1), (w * d).sum(1), (w * d * d).sum(1)
    t0, t1 = w @ points, (w * d) @ points
    den = s0 * s2 - s1**2
    ok = den > 1e-12 * np.maximum(s0 * s2, 1e-300)
    out = points.copy()
    out[ok] = (s2[ok, None] * t0[ok] - s1[ok, None] * t1[ok]) / den[ok, None]
    return out


def _arclen(points: np.ndarray, h_mm: float = 2.0, chord_mm: float = 2.0) -> np.ndarray:
    """Arc length along a measured (noisy) polyline.

    Summing short noisy segments overestimates the length (0.1 mm of noise on
    points 0.5 mm apart adds ~8 %), so the length is measured along a smoothed
    copy (local linear fit over ~2 mm, which shortens a 1/60 mm bend by
    < 0.06 %) in chords of ~2 mm; each point gets the length of its smoothed
    counterpart.
    """
    raw = arc_length(points)
    if raw[-1] <= 0:
        return raw
    sm = _smooth(points, raw, h_mm) if len(points) > 3 else points
    n = max(1, int(round(raw[-1] / chord_mm)))
    anchors = np.searchsorted(raw, np.linspace(0.0, raw[-1], n + 1)).clip(0, len(raw) - 1)
    anchors[0], anchors[-1] = 0, len(raw) - 1
    anchors = np.unique(anchors)
    at = arc_length(sm[anchors])
    return np.interp(raw, raw[anchors], at)


def _start_arc_length(points: np.ndarray, c: np.ndarray, bb: Backbone) -> float:
    """Where on the model backbone the measured polyline starts.

    The mean of ``sigma_k - c_k`` over the first half of the measured points
    (``sigma_k``: arc length of the model point closest to point k, ``c_k`` its
    arc length along the measurement): model errors grow along the backbone,
    so the half nearer the base places the measurement best.
    """
    sm = bb.s_mm
    if len(sm) < 2:
        return 0.0
    half = c <= 0.5 * c[-1]
    if half.sum() < 2:
        half = np.ones(len(c), bool)
    sigma = closest_arc_length(points[half], bb.p_world_mm, sm)[0]
    off = sigma - c[half]
    inner = (sigma > sm[0] + 1e-6) & (sigma < sm[-1] - 1e-6)
    return float(np.mean(off[inner] if inner.sum() >= 2 else off))


def compare(points_mm, bb: Backbone) -> dict:
    """Errors of a model backbone ``bb`` against a measured one (world mm, base first).

    Returns
    -------
    dict
        ``tip_error_mm`` (measured last point to model tip), ``mean_error_mm``
        (closest-point distances both directions, pooled, the model taken from
        where the measurement starts), ``max_error_mm`` (their maximum),
        ``length_error_mm`` (measured minus model length over the same span),
        ``s_start_mm`` (where the measurement starts on the model) and per
        measured point ``s_mm`` and ``along_error_mm`` (distance to the model
        point at the same arc length).
    """
    q = np.asarray(points_mm, float).reshape(-1, 3)
    if len(q) < 2:
        raise ModelFitError("measured backbone has fewer than 2 points")
    c = _arclen(q)
    s0 = _start_arc_length(q, c, bb)
    s = s0 + c
    along = np.linalg.norm(q - _at(bb, s), axis=1)
    keep = bb.s_mm >= s0
    model = bb.p_world_mm[keep] if keep.sum() >= 2 else bb.p_world_mm
    if s0 > bb.s_mm[0]:
        model = np.vstack([_at(bb, np.array([s0])), model])
    d = np.concatenate([point_to_polyline_distances(q, model), point_to_polyline_distances(model, q)])
    return {
        "tip_error_mm": float(np.linalg.norm(q[-1] - bb.p_world_mm[-1])),
        "mean_error_mm": float(d.mean()),
        "max_error_mm": float(d.max()),
        "length_error_mm": float(c[-1] - (bb.s_mm[-1] - max(s0, bb.s_mm[0]))),
        "s_start_mm": s0,
        "s_mm": s,
        "along_error_mm": along,
    }


def verify(frames: list, state: ModelState, ds_mm: float = 0.25) -> list:
    """Compare the model with every frame.

    Returns a list of per-frame dicts: ``frame``, ``status`` ("ok" or
    "model failed"), ``reason``, the errors of :func:`compare`, and the
    predicted backbone (``predicted_mm``).
    """
    out = []
    for fr in frames:
        rec = {"frame": fr.index, "status": "ok", "reason": None}
        try:
            bb = predict(state, fr.joints, ds_mm)
        except ValueError as exc:
            rec.update(status="model failed", reason=str(exc).splitlines()[0])
            out.append(rec)
            continue
        rec.update(compare(fr.points_mm, bb))
        rec["predicted_mm"] = bb.p_world_mm
        out.append(rec)
    return out


def aggregate(records: list) -> dict:
    """Means, medians and maxima of per-frame errors (ok frames)."""
    ok = [r for r in records if r["status"] == "ok"]
    res = {"frames": len(records), "ok_frames": len(ok), "failed_frames": len(records) - len(ok)}
    for key in ("tip_error_mm", "mean_error_mm", "max_error_mm"):
        v = np.array([r[key] for r in ok], float)
        res[f"{key}_mean"] = float(v.mean()) if v.size else None
        res[f"{key}_median"] = float(np.median(v)) if v.size else None
        res[f"{key}_max"] = float(v.max()) if v.size else None
    if ok:
        a = np.concatenate([r["along_error_mm"] for r in ok])
        res["along_error_mm_rms"] = float(np.sqrt(np.mean(a**2)))
    return res


def along_profile(records: list, bin_mm: float = 2.0) -> dict:
    """Error along the arc length, pooled over frames: bin centres, mean, 90th percentile, count."""
    ok = [r for r in records if r["status"] == "ok"]
    if not ok:
        return {"s_mm": [], "mean_mm": [], "p90_mm": [], "n": []}
    s = np.concatenate([r["s_mm"] for r in ok])
    e = np.concatenate([r["along_error_mm"] for r in ok])
    edges = np.arange(np.floor(s.min() / bin_mm) * bin_mm, s.max() + bin_mm, bin_mm)
    idx = np.clip(np.digitize(s, edges) - 1, 0, len(edges) - 2)
    cen, mean, p90, n = [], [], [], []
    for b in range(len(edges) - 1):
        m = idx == b
        if m.any():
            cen.append(0.5 * (edges[b] + edges[b + 1]))
            mean.append(float(e[m].mean()))
            p90.append(float(np.percentile(e[m], 90)))
            n.append(int(m.sum()))
    return {"s_mm": cen, "mean_mm": mean, "p90_mm": p90, "n": n}


# ----------------------------------------------------------------------------- parameters
@dataclass
class _Work:
    """Mutable copy of a model state that parameter setters write into."""

    tubes: list
    T: np.ndarray
    rot: np.ndarray
    ins: np.ndarray
    model: str

    @classmethod
    def of(cls, st: ModelState) -> "_Work":
        return cls([dict(t.__dict__) for t in st.robot.tubes], st.robot.T_world_base.copy(),
                   np.array(st.offsets.rotation_deg, float), np.array(st.offsets.extension_mm, float), st.model)

    def state(self) -> ModelState:
        robot = Robot(tubes=tuple(Tube(**t) for t in self.tubes), T_world_base=self.T)
        return ModelState(robot, self.model, JointOffsets(self.ins.copy(), self.rot.copy()))


def _second_moment(t: dict) -> float:
    return np.pi / 64.0 * (t["outer_diameter_mm"] ** 4 - t["inner_diameter_mm"] ** 4)


@dataclass
class Param:
    """One scalar fit parameter.

    ``name`` as reported (e.g. ``inner.precurvature_per_mm``,
    ``base.position_mm[x]``), ``unit``, ``scale`` (typical change, for
    scaling), ``lower``/``upper`` bounds, and ``get(work)``/``set(work, v)``.
    """

    name: str
    unit: str
    scale: float
    lower: float
    upper: float
    get: object
    set: object
    group: str = ""


_TUBE_KEYS = {
    "precurvature_per_mm": ("1/mm", 0.0, np.inf),
    "curved_length_mm": ("mm", 0.0, np.inf),
    "length_mm": ("mm", 1e-6, np.inf),
    "youngs_modulus_gpa": ("GPa", 1e-6, np.inf),
    "poisson_ratio": ("", -0.999, 0.499),
}

PARAM_HELP = (
    "<tube>.precurvature_per_mm, <tube>.curved_length_mm, <tube>.length_mm, <tube>.youngs_modulus_gpa, "
    "<tube>.poisson_ratio, stiffness_ratio, stiffness_ratio.<tube>, rotation_offset_deg.<tube>, "
    "insertion_offset_mm.<tube>, base.position_mm, base.rotation_deg"
)


def _tube_index(robot: Robot, key: str, full: str) -> int:
    names = [t.name for t in robot.tubes]
    if key in names:
        return names.index(key)
    if key.isdigit() and int(key) < robot.n_tubes:
        return int(key)
    raise ModelFitError(f"parameter {full!r}: no tube {key!r} (tubes: {', '.join(names)}, or 0..{robot.n_tubes - 1})")


def parse_params(names, state: ModelState) -> list:
    """Fit parameters from their names (see the module docstring); ModelFitError for a bad name.

    Refuses combinations that shapes cannot identify (every tube's Young's
    modulus; a stiffness ratio together with a modulus it involves;
    ``poisson_ratio`` or ``length_mm`` with the bending model, which does not
    depend on them).
    """
    robot = state.robot
    n = robot.n_tubes
    names = [x.strip() for x in (names.split(",") if isinstance(names, str) else names) if x.strip()]
    if not names:
        raise ModelFitError(f"no parameters to fit; choose from: {PARAM_HELP}")
    out, seen = [], set()
    moduli, ratios = set(), set()
    for full in names:
        if full in seen:
            raise ModelFitError(f"parameter {full!r} listed twice")
        seen.add(full)
        head, _, rest = full.partition(".")
        if head == "base" and rest in ("position_mm", "rotation_deg"):
            for a, ax in enumerate("xyz"):
                if rest == "position_mm":
                    out.append(Param(f"base.position_mm[{ax}]", "mm", 1.0, -np.inf, np.inf,
                                     (lambda w, a=a: w.T[a, 3]), (lambda w, v, a=a: w.T.__setitem__((a, 3), v)), "base"))
                else:
                    out.append(Param(f"base.rotation_deg[{ax}]", "deg", 0.5, -180.0, 180.0, None, None, "base.rotation"))
            continue
        if head in ("rotation_offset_deg", "insertion_offset_mm") and rest:
            i = _tube_index(robot, rest, full)
            arr = "rot" if head == "rotation_offset_deg" else "ins"
            out.append(Param(full, "deg" if arr == "rot" else "mm", 1.0, -np.inf, np.inf,
                             (lambda w, i=i, arr=arr: getattr(w, arr)[i]),
                             (lambda w, v, i=i, arr=arr: getattr(w, arr).__setitem__(i, v))))
            continue
        if head == "stiffness_ratio":
            if rest:
                i = _tube_index(robot, rest, full)
            elif n == 2:
                i = 1
            else:
                raise ModelFitError(f"parameter {full!r}: with {n} tubes say which: stiffness_ratio.<tube> (E I of that tube / E I of the outermost)")
            if i == 0:
                raise ModelFitError(f"parameter {full!r}: the ratio is relative to the outermost tube; choose another tube")
            ratios.add(i)

            def get(w, i=i):
                return w.tubes[i]["youngs_modulus_gpa"] * _second_moment(w.tubes[i]) / (w.tubes[0]["youngs_modulus_gpa"] * _second_moment(w.tubes[0]))

            def set_(w, v, i=i):
                w.tubes[i]["youngs_modulus_gpa"] = v * w.tubes[0]["youngs_modulus_gpa"] * _second_moment(w.tubes[0]) / _second_moment(w.tubes[i])

            out.append(Param(f"stiffness_ratio.{robot.tubes[i].name}", "", 0.0, 1e-9, np.inf, get, set_))
            continue
        if rest in _TUBE_KEYS:
            i = _tube_index(robot, head, full)
            unit, lo, hi = _TUBE_KEYS[rest]
            if rest in ("poisson_ratio", "length_mm") and state.model == "bending":
                raise ModelFitError(f"parameter {full!r}: the bending model does not depend on it (use --model compliant)")
            if rest == "youngs_modulus_gpa":
                moduli.add(i)
            out.append(Param(f"{robot.tubes[i].name}.{rest}", unit, 0.0, lo, hi,
                             (lambda w, i=i, k=rest: w.tubes[i][k]), (lambda w, v, i=i, k=rest: w.tubes[i].__setitem__(k, v))))
            continue
        raise ModelFitError(f"unknown parameter {full!r}; known: {PARAM_HELP}")
    if n > 1 and len(moduli) == n:
        raise ModelFitError(
            "cannot fit every tube's youngs_modulus_gpa: without external loads the shape depends only on ratios of E I; "
            "fit stiffness_ratio (or all but one tube's modulus)"
        )
    if n == 1 and moduli:
        raise ModelFitError("youngs_modulus_gpa of a single tube does not change its unloaded shape; it cannot be fitted")
    if ratios and moduli & (ratios | {0}):
        raise ModelFitError("stiffness_ratio and youngs_modulus_gpa of the same tubes cannot be fitted together (only E I ratios are identifiable)")
    rots = {p.name for p in out if p.name.startswith("rotation_offset_deg.")}
    if "base.rotation_deg[z]" in {p.name for p in out} and len(rots) == n:
        raise ModelFitError("base.rotation_deg about the insertion axis and a rotation offset on every tube are the same motion; drop one")
    # typical scales (for conditioning) from the starting values
    work = _Work.of(state)
    for p in out:
        if p.group == "base.rotation":
            continue
        if p.scale == 0.0:
            v = abs(p.get(work))
            p.scale = 0.1 * v if v > 0 else (1e-3 if p.unit == "1/mm" else 1.0)
    return out


def _apply(params: list, values: np.ndarray, base: ModelState) -> ModelState:
    w = _Work.of(base)
    rotv = np.zeros(3)
    for p, v in zip(params, values):
        if p.group == "base.rotation":
            rotv["xyz".index(p.name[-2])] = v
        else:
            p.set(w, float(v))
    if np.any(rotv):
        w.T[:3, :3] = w.T[:3, :3] @ rotation_from_rotvec(np.deg2rad(rotv))
    return w.state()


def _initial(params: list, state: ModelState) -> np.ndarray:
    w = _Work.of(state)
    return np.array([0.0 if p.group == "base.rotation" else float(p.get(w)) for p in params])


# ----------------------------------------------------------------------------- fitting
@dataclass(frozen=True, eq=False)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    state : ModelState
        The fitted robot, model and joint offsets.
    names, units : list of str
    initial, values, std : (p,) arrays
        Starting values, estimates and standard errors.
    ci95 : (p, 2) array
        95 % confidence intervals, ``value -+ t_{0.975, m-p} std`` with
        ``cov = s^2 (J^T J)^-1`` (J the Jacobian of the residuals at the
        solution, s^2 the residual variance). They treat residuals as
        independent; points along one backbone are correlated, so these are
        optimistic.
    ci95_frames : (p, 2) array
        The same from the frame-clustered sandwich covariance
        ``(J^T J)^-1 (sum_f J_f^T r_f r_f^T J_f) (J^T J)^-1``, which allows any
        correlation within a frame (needs more frames than parameters).
    rms_mm : float
        RMS residual (per component) at the solution.
    frames : list of int
        Frames used in the fit.
    dropped : list of (int, str)
        Frames left out because the starting model failed on them.
    """

    state: ModelState
    names: list
    units: list
    initial: np.ndarray
    values: np.ndarray
    std: np.ndarray
    ci95: np.ndarray
    ci95_frames: np.ndarray
    rms_mm: float
    cost: float
    nfev: int
    message: str
    frames: list
    dropped: list
    n_residuals: int
    warnings: list = field(default_factory=list)

    def table(self) -> list:
        """One dict per parameter (JSON-ready)."""
        rows = []
        for k, name in enumerate(self.names):
            rows.append({
                "name": name, "unit": self.units[k], "initial": float(self.initial[k]), "value": float(self.values[k]),
                "std": _num(self.std[k]), "ci95": [_num(self.ci95[k, 0]), _num(self.ci95[k, 1])],
                "ci95_frames": [_num(self.ci95_frames[k, 0]), _num(self.ci95_frames[k, 1])],
            })
        return rows


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


class _Problem:
    """Residual function over frames for a parameter list."""

    def __init__(self, frames, base: ModelState, params, step_mm, tip_weight, ds_mm):
        self.base, self.params, self.tip_weight, self.ds = base, params, tip_weight, ds_mm
        self.meas = []
        for fr in frames:
            q = resample_polyline(np.asarray(fr.points_mm, float), step_mm)
            if len(q) < 2:
                raise ModelFitError(f"frame {fr.index}: measured backbone has fewer than 2 points")
            self.meas.append((fr, q, _arclen(q)))
        self.x0 = _initial(params, base)
        self.scale = np.array([p.scale for p in params])
        self.sizes = [3 * len(q) + 3 for _, q, _ in self.meas]
        self.failed = None

    def state(self, z):
        return _apply(self.params, self.x0 + self.scale * z, self.base)

    def frame_residuals(self, st, k):
        fr, q, c = self.meas[k]
        bb = predict(st, fr.joints, self.ds)
        s = _start_arc_length(q, c, bb) + c
        r = (q - _at(bb, s)).ravel()
        tip = self.tip_weight * (q[-1] - bb.p_world_mm[-1])
        return np.concatenate([r, tip])

    def __call__(self, z):
        try:
            st = self.state(z)
        except ValueError as exc:  # e.g. a curved length beyond the tube's length
            self.failed = ("all", str(exc).splitlines()[0])
            return np.full(sum(self.sizes), 1e3)
        out = []
        for k in range(len(self.meas)):
            try:
                out.append(self.frame_residuals(st, k))
            except ValueError as exc:
                # The model failed here (e.g. compliant snapping): a large residual
                # makes the trust region step back.
                self.failed = (self.meas[k][0].index, str(exc).splitlines()[0])
                out.append(np.full(self.sizes[k], 1e3))
        return np.concatenate(out)


def split_holdout(frames: list, k: int | None) -> tuple:
    """``(fit_frames, held_out)``: every ``k``-th frame (the k-th, 2k-th, ...) held out; none if k is None or 0."""
    if not k:
        return list(frames), []
    if k < 2:
        raise ModelFitError(f"--holdout-every must be >= 2 (every k-th frame held out), got {k}")
    held = [f for j, f in enumerate(frames) if (j + 1) % k == 0]
    fit_ = [f for j, f in enumerate(frames) if (j + 1) % k != 0]
    if not held:
        raise ModelFitError(f"--holdout-every {k}: fewer than {k} frames, nothing to hold out")
    return fit_, held


def fit(frames: list, state: ModelState, params, *, loss: str = "soft_l1", f_scale_mm: float = 1.0,
        step_mm: float = 1.0, tip_weight: float = 1.0, ds_mm: float = 0.25, max_nfev: int | None = None,
        verbose: int = 0) -> FitResult:
    """Estimate parameters by nonlinear least squares over ``frames``.

    Parameters
    ----------
    frames : list of Frame
    state : ModelState
        Starting robot, model and joint offsets (the nominal ones).
    params : list of str or of Param
        Names (see the module docstring) or :func:`parse_params` output.
    loss : str
        ``scipy.optimize.least_squares`` loss: linear, soft_l1 (default),
        huber, cauchy or arctan; robust losses down-weight residuals beyond
        ``f_scale_mm`` (reconstruction outliers, a truncated tip).
    step_mm : float
        Measured backbones are resampled at this arc-length step.
    tip_weight : float
        Weight of the tip residual (per component) relative to a point's.
    ds_mm : float
        Sample spacing of the model backbones.

    Returns
    -------
    FitResult
    """
    if loss not in LOSSES:
        raise ModelFitError(f"unknown loss {loss!r}; expected one of {', '.join(LOSSES)}")
    if not f_scale_mm > 0 or not step_mm > 0 or not ds_mm > 0 or not tip_weight >= 0:
        raise ModelFitError("f_scale_mm, step_mm and ds_mm must be > 0 and tip_weight >= 0")
    if not frames:
        raise ModelFitError("no frames to fit")
    params = parse_params(params, state) if not (params and isinstance(params[0], Param)) else params
    usable, dropped = _usable_frames(frames, state, ds_mm)
    prob = _Problem(usable, state, params, step_mm, tip_weight, ds_mm)
    p = len(params)
    lo = np.minimum([(pp.lower - x) / s for pp, x, s in zip(params, prob.x0, prob.scale)], -1e-6)
    hi = np.maximum([(pp.upper - x) / s for pp, x, s in zip(params, prob.x0, prob.scale)], 1e-6)
    res = least_squares(prob, np.zeros(p), jac="2-point", bounds=(lo, hi), diff_step=1e-3, loss=loss,
                        f_scale=f_scale_mm, x_scale=1.0, max_nfev=max_nfev or 60 * (p + 1), verbose=verbose,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10)
    values = prob.x0 + prob.scale * res.x
    std, ci, ci_f, warnings = _intervals(prob, res, values, lo, hi, loss, f_scale_mm)
    warnings += _fit_warnings(params, prob, res, values, lo, hi)
    r = res.fun
    return FitResult(
        state=prob.state(res.x), names=[pp.name for pp in params], units=[pp.unit for pp in params],
        initial=prob.x0.copy(), values=values, std=std, ci95=ci, ci95_frames=ci_f,
        rms_mm=float(np.sqrt(np.mean(r**2))), cost=float(res.cost), nfev=int(res.nfev), message=str(res.message),
        frames=[fr.index for fr, _, _ in prob.meas], dropped=dropped, n_residuals=int(r.size), warnings=warnings,
    )


def _usable_frames(frames: list, state: ModelState, ds_mm: float) -> tuple:
    """``(usable, dropped)``: frames the starting model predicts, and ``(index, why)`` of the others.

    Frames on which the starting model fails cannot guide the fit; ModelFitError if it fails on all.
    """
    usable, dropped = [], []
    for fr in frames:
        try:
            predict(state, fr.joints, ds_mm)
            usable.append(fr)
        except ValueError as exc:
            dropped.append((fr.index, str(exc).splitlines()[0]))
    if not usable:
        raise ModelFitError(f"the starting model fails on every frame (frame {dropped[0][0]}: {dropped[0][1]})")
    return usable, dropped


def _intervals(prob: _Problem, res, values: np.ndarray, lo: np.ndarray, hi: np.ndarray, loss: str,
               f_scale_mm: float) -> tuple:
    """``(std, ci95, ci95_frames, warnings)`` of the estimates (see :class:`FitResult`); NaN where not computable."""
    p = values.size
    r = res.fun
    warnings = []
    # Central-difference Jacobian at the solution (raw residuals), weighted as the
    # robust loss weights each residual (IRLS weights sqrt(rho'(r^2 / f^2))).
    J = _jacobian(prob, res.x, r, lo, hi)
    wts = np.sqrt(_rho_prime(loss, (r / f_scale_mm) ** 2))
    Jw, rw = J * wts[:, None], r * wts
    dof = max(r.size - p, 1)
    s2 = float(rw @ rw) / dof
    D = np.diag(prob.scale)
    std = np.full(p, np.nan)
    ci = np.full((p, 2), np.nan)
    ci_f = np.full((p, 2), np.nan)
    tq = float(student_t.ppf(0.975, dof))
    JtJ = Jw.T @ Jw
    try:
        sv = np.linalg.svd(Jw, compute_uv=False)
        if sv[-1] <= 1e-9 * sv[0]:
            raise np.linalg.LinAlgError
        inv = np.linalg.inv(JtJ)
        cov = D @ (s2 * inv) @ D
        std = np.sqrt(np.diag(cov))
        ci = np.stack([values - tq * std, values + tq * std], axis=1)
        nf = len(prob.meas)
        if nf > p:
            meat = np.zeros((p, p))
            start = 0
            for size in prob.sizes:
                g = Jw[start:start + size].T @ rw[start:start + size]
                meat += np.outer(g, g)
                start += size
            cov_f = D @ (inv @ meat @ inv) @ D * nf / (nf - 1)
            std_f = np.sqrt(np.diag(cov_f))
            tf = float(student_t.ppf(0.975, nf - 1))
            ci_f = np.stack([values - tf * std_f, values + tf * std_f], axis=1)
        else:
            warnings.append(f"frame-clustered intervals need more frames ({nf}) than parameters ({p})")
    except np.linalg.LinAlgError:
        warnings.append("the parameters are not identifiable together from these frames (singular J^T J): no confidence intervals")
    return std, ci, ci_f, warnings


def _fit_warnings(params: list, prob: _Problem, res, values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list:
    """What makes the estimates doubtful: parameters at a bound, model failures during the fit, no convergence."""
    warnings = []
    for k, pp in enumerate(params):
        if res.x[k] - lo[k] < 1e-6 or hi[k] - res.x[k] < 1e-6:
            warnings.append(f"{pp.name} ended at its bound ({values[k]:.6g}): the data push it beyond what is physical; "
                            "its interval is meaningless (a model-form error, or a parameter the frames do not constrain)")
    if prob.failed is not None:
        where = "" if prob.failed[0] == "all" else f" on frame {prob.failed[0]}"
        warnings.append(f"the model failed during the fit{where} ({prob.failed[1]}); those steps were rejected")
    if not res.success:
        warnings.append(f"least squares did not converge: {res.message}")
    return warnings


def _rho_prime(loss: str, z: np.ndarray) -> np.ndarray:
    if loss == "linear":
        return np.ones_like(z)
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1e-300)))
    if loss == "cauchy":
        return 1.0 / (1.0 + z)
    return 1.0 / (1.0 + z**2)  # arctan


def _jacobian(prob: _Problem, z: np.ndarray, r0: np.ndarray, lo: np.ndarray, hi: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Central differences (one-sided next to a bound) of the residuals in scaled units."""
    J = np.empty((r0.size, z.size))
    for k in range(z.size):
        e = np.zeros_like(z)
        e[k] = h
        if z[k] - h < lo[k]:
            J[:, k] = (prob(z + e) - r0) / h
        elif z[k] + h > hi[k]:
            J[:, k] = (r0 - prob(z - e)) / h
        else:
            J[:, k] = (prob(z + e) - prob(z - e)) / (2 * h)
    return J
