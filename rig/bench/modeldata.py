"""Reconstructed (or true) backbones paired with the joints recorded for them: what ``verify`` and ``fit`` work on.

:func:`load_dataset` reads a run directory through :mod:`rig.rundir`'s reader (or a twin
session's ground truth) and the nominal robot the session records.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rig.rundir import read_run
from rig.session import Session
from twin.modelfit import Frame, ModelFitError, ModelState, load_robot_file, robot_from_dict
from twin.robot import Joints

__all__ = ["Dataset", "load_dataset"]


@dataclass
class Dataset:
    """Measured frames with their recorded joints, and the nominal model."""

    frames: list
    state: object                 # twin.modelfit.ModelState (nominal, or --robot)
    source: str                   # "reconstruction" or "ground truth"
    recon_dir: Path
    session_dir: Path
    robot_source: str
    skipped: list = field(default_factory=list)   # (frame, reason)


def _resolve_session(recon: Path, named: str | None) -> Path:
    if named is None:
        raise ValueError(f"{recon / 'summary.json'}: names no session; pass --session DIR")
    p = Path(named)
    cands = [p] if p.is_absolute() else [Path.cwd() / p, recon / p, recon.parent / p, recon / "session"]
    if not p.is_absolute():
        # a path recorded relative to wherever reconstruct ran: try its tail under the recon dir's parents
        cands += [anc / p.name for anc in (recon, recon.parent)]
    for c in cands:
        if (c / "session.json").exists():
            return c
    raise ValueError(f"{recon / 'summary.json'}: its session {named!r} was not found (looked in {', '.join(str(c) for c in cands[:4])}); pass --session DIR")


def load_dataset(path, session=None, robot=None, model=None, frames=None) -> Dataset:
    """Frames (recorded joints + measured backbone) and the nominal model state.

    Parameters
    ----------
    path : reconstruction output directory, or a twin session with ground truth
    session : session directory overriding the one summary.json names
    robot : robot TOML file overriding the session's nominal robot
    model : "bending" or "compliant" (default: the robot's model)
    frames : set of frame indices to use (default: all)
    """
    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"{path}: not a directory (expected a reconstruction output directory or a session)")
    measured, failed = {}, {}
    if (path / "summary.json").exists():
        # only what the summary lists: never a stale backbones.npz or frame CSV of another run
        summary, measured = read_run(path)
        sdir = Path(session) if session else _resolve_session(path, summary.get("session"))
        failed = {int(r["frame"]): r.get("reason") or "failed" for r in summary.get("per_frame", []) if r.get("status") != "ok"}
        source = "reconstruction"
        sess = Session(sdir)
    elif (path / "session.json").exists():
        sdir = Path(session) if session else path
        sess = Session(sdir)
        if not sess.has_truth:
            raise ValueError(f"{path}: a session without ground truth; reconstruct it first (ctr-bench reconstruct) and verify the output directory")
        for fr in sess.frames:
            t = sess.truth(fr.index)
            if t is not None:
                measured[fr.index] = np.asarray(t["backbone_world_mm"], float)
        source = "ground truth"
    else:
        raise ValueError(f"{path}: neither a reconstruction output directory (summary.json) nor a session directory (session.json)")
    if robot is not None:
        state = load_robot_file(robot)
        robot_source = str(robot)
    else:
        if "robot" not in sess.meta:
            raise ValueError(f"{sess.dir / 'session.json'}: no nominal robot recorded; pass --robot ROBOT.toml")
        if sess.meta["robot"].get("diameters_only"):
            raise ValueError(f"{sess.dir / 'session.json'}: records only the tube diameters (ctr-bench import "
                             "--tube-diameters-mm), not a robot model; pass --robot ROBOT.toml")
        r, m = robot_from_dict(sess.meta["robot"], str(sess.dir / "session.json"))
        state = ModelState(r, m)
        robot_source = str(sess.dir / "session.json")
    if model is not None:
        state = ModelState(state.robot, model, state.offsets)
    if sess.n_tubes and sess.n_tubes != state.robot.n_tubes:
        raise ModelFitError(f"{robot_source}: robot has {state.robot.n_tubes} tubes but the session records joints of {sess.n_tubes}")
    wanted = frames
    frames, skipped = [], []
    for fr in sess.frames:
        if wanted is not None and fr.index not in wanted:
            continue
        if fr.extension_mm is None:
            skipped.append((fr.index, "no joint values"))
        elif fr.index not in measured:
            skipped.append((fr.index, f"no backbone ({failed[fr.index]})" if fr.index in failed else "no backbone"))
        elif len(measured[fr.index]) < 2:
            skipped.append((fr.index, "backbone has fewer than 2 points"))
        else:
            frames.append(Frame(fr.index, Joints(fr.extension_mm, fr.rotation_deg), measured[fr.index]))
    if not frames:
        nj = sum(1 for _, why in skipped if why == "no joint values")
        raise ModelFitError(
            f"{path}: no frame has both joint values and a measured backbone "
            f"({nj} of {len(skipped)} frames without joint values, {len(skipped) - nj} without a backbone)"
        )
    return Dataset(frames, state, source, path, sess.dir, robot_source, skipped)
