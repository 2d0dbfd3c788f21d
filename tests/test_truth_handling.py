"""A frame's bad ground truth costs that frame's score only, with a note naming the file (issue 15, item 8).

A tiny synthetic session (32x24 images written with the session writer, no
rendering) has four frames: frame 0's truth is good, frame 1's file is missing
(the session says it has ground truth), frame 2's is not an npz archive, and
frame 3's backbone is (n, 2). The scorers of the wide bench and of
``ctr-bench bench`` keep every frame, score frame 0 and note the others.
"""
from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rig.bench import compare, widebench
from rig.cli.commands import bench
from rig.session import Session
from tiny_session import tiny_backbone, tiny_rig, write_tiny_session

@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A valid session: 2 cameras, 2 tubes, 6 background pairs, 4 frames with ground truth."""
    return write_tiny_session(tmp_path_factory.mktemp("truth") / "session", 4,
                              lambda rig, f: {"backbone_world_mm": tiny_backbone(f)})


def _spoil(d: Path, frames=(1, 2, 3)) -> dict:
    """Spoil the truth of ``frames``: 1 missing, 2 not an npz, 3 a (n, 2) backbone; their paths by frame."""
    paths = {f: d / "truth" / f"{f:06d}.npz" for f in frames}
    if 1 in paths:
        paths[1].unlink()
    if 2 in paths:
        paths[2].write_bytes(b"this is not an npz archive")
    if 3 in paths:
        np.savez(paths[3], backbone_world_mm=tiny_backbone(3)[:, :2])
    return paths


@pytest.fixture
def spoiled(template, tmp_path) -> tuple:
    d = tmp_path / "session"
    shutil.copytree(template, d)
    return d, _spoil(d)


def _assert_note(note, path: Path) -> None:
    assert note is not None and note.startswith("not scored: "), note
    assert str(path) in note and "\n" not in note, note


def test_score_run_keeps_every_frame_and_notes_the_bad_truths(spoiled):
    d, bad = spoiled
    session = Session(d)
    # What a summary would hold if something had scored the bad truths anyway: a 30 mm error.
    recs = [{"frame": f, "status": "ok", "mean_error_mm": 0.05 if f == 0 else 20.0,
             "max_error_mm": 0.1 if f == 0 else 30.0, "tip_error_mm": 0.1, "ms": 3.0} for f in range(4)]
    rows = widebench.score_run({"per_frame": recs}, session, "s", "fast", {"backdrop": "plain"})
    assert [r["frame"] for r in rows] == [0, 1, 2, 3]
    assert rows[0]["note"] is None and rows[0]["max_error_px"] is not None and np.isfinite(rows[0]["footprint_mm"])
    for row in rows[1:]:
        _assert_note(row["note"], bad[row["frame"]])
        assert row["status"] == "ok" and row["max_error_mm"] is None and row["max_error_px"] is None
        assert not row["silent_wrong"]
    assert "missing" in rows[1]["note"] and "(20, 2)" in rows[3]["note"]
    a = widebench.aggregate(rows)
    assert (a["frames"], a["ok"], a["silent_wrong"], a["good"]) == (4, 4, 0, 1)
    assert a["max_error_mm_max"] == pytest.approx(0.1)  # the 30 mm of the bad frames is not counted
    assert "note" in widebench._CSV_FIELDS


def test_score_run_carries_the_reconstruct_note(template):
    rec = {"frame": 0, "status": "failed", "reason": "no silhouette", "note": "not scored: something"}
    row, = widebench.score_run({"per_frame": [rec]}, Session(template), "s", "fast", {})
    assert row["note"] == "not scored: something"  # frame 0's truth is good: the summary's own note stays
    fake = SimpleNamespace(rig=tiny_rig(), dir=template, truth=lambda i: None)  # a session without ground truth
    row, = widebench.score_run({"per_frame": [rec]}, fake, "s", "fast", {})
    assert row["note"] == f"not scored: {template}: the session has no ground truth"


def test_thinnest_tube_px_skips_a_bad_first_truth(template, tmp_path):
    good = widebench.thinnest_tube_px(Session(template))
    assert np.isfinite(good)
    d = tmp_path / "session"
    shutil.copytree(template, d)
    (d / "truth" / "000000.npz").write_bytes(b"garbage")
    assert widebench.thinnest_tube_px(Session(d)) == pytest.approx(good, rel=0.2)  # frame 1's truth instead
    for f in (1, 2, 3):
        (d / "truth" / f"{f:06d}.npz").unlink()
    assert np.isnan(widebench.thinnest_tube_px(Session(d)))


def test_bench_keeps_every_frame_and_notes_the_bad_truths(spoiled, monkeypatch, capsys):
    d, bad = spoiled
    data = compare.load_session(d)
    assert len(data["frames"]) == 4 and data["truths"][0] is not None and data["truths"][1:] == [None] * 3
    assert data["truth_notes"][0] is None
    for f in (1, 2, 3):
        _assert_note(data["truth_notes"][f], bad[f])

    class _Perfect:  # a method that returns frame k's true backbone at its k-th call
        def __init__(self):
            self.k = 0

        def reset(self):
            self.k = 0

        def __call__(self, frames):
            self.k += 1
            return SimpleNamespace(points_world_mm=tiny_backbone(self.k - 1))

    monkeypatch.setattr(compare, "make_method", lambda *a, **k: _Perfect())
    out = compare.run_method("fast", data, repeats=1, memory=False)
    assert out["frames"] == 4 and out["failed_frames"] == 0 and out["scored_frames"] == 1
    assert out["max_error_mm"] == pytest.approx(0.0, abs=1e-6)
    assert len(out["score_notes"]) == 3
    bench._print_score_notes({"fast": out, "paper": out})
    printed = capsys.readouterr().out
    assert "3 frame(s) not scored" in printed and all(str(p) in printed for p in bad.values())
