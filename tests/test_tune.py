"""``ctr-bench tune``: the search, its evaluation and the parameter file it writes."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from recon.fast import FastParams
from recon.paper import PaperParams
from recon.params import load_params
from rig.cli import main
from rig.scenefiles import scene_path
from rig.bench.tune import (KNOBS, Evaluator, Knob, evaluate, knob_values, load_tune_session, tune, tune_session_dirs, tuned_dict,
                            with_knobs)

ROOT = Path(__file__).resolve().parents[1]
#: A tuning scene: dim, flickering light, noisy sensor; 4 frames, 10 background frames.
SCENE = scene_path("tune", "dim-flicker.toml")
THRESHOLD = next(k for k in KNOBS["paper"] if k.path == "silhouette.threshold")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("tune-cache")


@pytest.fixture(scope="module")
def session_dirs(cache):
    return tune_session_dirs([SCENE], cache, log=lambda *_: None)


@pytest.fixture(scope="module")
def sessions(session_dirs):
    return [load_tune_session(str(d)) for d in session_dirs]


def test_every_knob_names_a_parameter_and_its_default_is_in_range():
    for method, cls in (("paper", PaperParams), ("fast", FastParams)):
        x = knob_values(cls(), KNOBS[method])  # raises AttributeError for a wrong path
        for k, v in zip(KNOBS[method], x):
            assert k.low <= v <= k.high, (method, k.path, v)


def test_with_knobs_rounds_integers_clips_to_range_and_sets_nested_fields():
    knobs = (Knob("background.k", 1, 8, integer=True), Knob("silhouette.threshold", 0.05, 0.6, step=0.005))
    p = with_knobs(PaperParams(), knobs, [3.6, 0.9])
    assert p.background.k == 4 and isinstance(p.background.k, int)
    assert p.silhouette.threshold == 0.6
    assert with_knobs(PaperParams(), knobs, [1, 0.23713]).silhouette.threshold == 0.235
    assert p.silhouette.min_contrast == PaperParams().silhouette.min_contrast  # siblings untouched
    assert list(knob_values(p, knobs)) == [4.0, 0.6]


def test_sessions_carry_the_scene_robot_tube_radii(sessions):
    (s,) = sessions
    assert s.tube_radii_mm == (0.8, 0.5)
    assert len(s.frames) == len(s.truths) == 4
    assert all(stack.shape[0] == 10 for stack in s.backgrounds.values())


def _without_hysteresis(threshold: float) -> PaperParams:
    """The paper's single threshold (no hysteresis low threshold, which rescues a too-high one since issue 13)."""
    return replace(PaperParams(), silhouette=replace(PaperParams().silhouette, threshold=threshold, hysteresis_sigma=0.0))


def test_a_failed_frame_costs_the_penalty(sessions):
    broken = _without_hysteresis(0.7)
    ev = evaluate("paper", broken, sessions, failure_penalty_mm=7.0)
    assert ev.failures == ev.frames == 4
    assert ev.penalized_error_mm == 7.0 and np.isnan(ev.mean_error_mm)


def test_evaluation_on_dask_workers_gives_the_serial_errors_and_resumes_from_its_journal(sessions, session_dirs, tmp_path):
    params = [with_knobs(PaperParams(), (THRESHOLD,), [t]) for t in (0.15, 0.3)]
    serial = [evaluate("paper", p, sessions) for p in params]
    journal = tmp_path / "tune.jsonl"
    with Evaluator("paper", session_dirs, journal=journal, workers=2) as ev:
        parallel = ev.many(params)
    for a, b in zip(serial, parallel):
        assert a.mean_error_mm == b.mean_error_mm and a.failures == b.failures and a.per_session == b.per_session
    lines = journal.read_text().splitlines()
    assert len(lines) == len(params) * len(session_dirs)
    with Evaluator("paper", session_dirs, journal=journal, workers=1) as ev:  # a re-run: nothing evaluated again
        again = ev.many(params)
    assert journal.read_text().splitlines() == lines
    assert [a.penalized_error_mm for a in again] == [b.penalized_error_mm for b in parallel]


def test_tuner_recovers_a_threshold_that_loses_the_robot(session_dirs):
    """Starting from a threshold at which every frame fails (0.7 on this dim scene, without the hysteresis), the
    search must find one at which none fails and the error is within a voxel; the sensitivity sweep covers the range."""
    base = _without_hysteresis(0.7)
    res = tune("paper", session_dirs, base, knobs=(THRESHOLD,), maxiter=3, popsize=5, seed=3, sensitivity_points=4,
               workers=0)
    assert res.default.failures == 4
    assert res.tuned.failures == 0
    assert res.tuned.mean_error_mm <= 1.0  # mm; the voxel edge here is ~1 mm
    assert THRESHOLD.low <= res.tuned_params.silhouette.threshold < 0.5
    assert [r["value"] for r in res.sensitivity] == pytest.approx(list(np.linspace(0.05, 0.6, 4)))
    assert {r["stage"] for r in res.history} == {"default", "search"}
    assert tuned_dict(res) == {"method": "paper", "silhouette": {"threshold": res.tuned_params.silhouette.threshold}}


def test_cli_writes_a_parameter_file_that_reconstruct_reads(cache, session_dirs, tmp_path, capsys):
    out = tmp_path / "tuned.toml"
    rc = main(["tune", str(SCENE), "--method", "paper", "--knobs", "silhouette.threshold,background.k", "--maxiter", "1",
               "--popsize", "2", "--points", "3", "--cache", str(cache), "--out", str(out), "--workers", "0", "--quiet"])
    assert rc == 0
    report = tmp_path / "tuned-tune"
    for name in ("history.csv", "summary.json", "sensitivity.png",
                 "sensitivity_silhouette_threshold.png", "sensitivity_background_k.png"):
        assert (report / name).stat().st_size > 0, name
    tuned = load_params(PaperParams, out, "paper")
    text = out.read_text()
    assert "method = \"paper\"" in text and "[silhouette]" in text and "[background]" in text
    assert tuned.carving == PaperParams().carving  # not searched: default
    # The file is what reconstruct --params reads; the session's robot supplies the tube radii.
    session = next(p for p in Path(cache).iterdir() if p.is_dir())
    rc = main(["reconstruct", str(session), "--params", str(out), "--out", str(tmp_path / "rec"), "--no-report", "--quiet"])
    assert rc == 0
    capsys.readouterr()
    # ...and refuses it for another method, in one line.
    rc = main(["reconstruct", str(session), "--method", "fast", "--params", str(out), "--out", str(tmp_path / "rec2"),
               "--no-report", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "parameters of method 'paper'" in err, err
    # Nothing is overwritten.
    rc = main(["tune", str(SCENE), "--out", str(out), "--cache", str(cache), "--quiet"])
    assert rc == 2 and "exists" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--knobs", "carving.nonsense"], "unknown carving.nonsense"),
    (["--maxiter", "0"], "--maxiter: must be >= 1"),
    (["--holdout", str(SCENE)], "also a tuning scene"),
])
def test_cli_bad_options_are_one_line_errors(tmp_path, capsys, argv, message):
    rc = main(["tune", str(SCENE), "--out", str(tmp_path / "t.toml"), "--cache", str(tmp_path), "--quiet", *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and message in err, err


@pytest.mark.parametrize("path", sorted((ROOT / "params").glob("*.toml")), ids=lambda p: p.name)
def test_shipped_tuned_files_load_for_their_method(path):
    from recon.methods import get_method
    from recon.params import read_params_file

    method = path.stem.split("-")[0]
    params = load_params(get_method(method).params_type, path, method)
    data = read_params_file(path, method)
    assert data, path
    # Only searched knobs are in the file, and each is inside its search range.
    for k in KNOBS[method]:
        v = knob_values(params, (k,))[0]
        assert k.low <= v <= k.high, (path.name, k.path, v)
