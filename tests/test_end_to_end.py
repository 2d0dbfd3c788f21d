"""A short twin scene rendered into a session and reconstructed with the paper's method, scored against the truth."""
from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

from rig.backbone_csv import read_backbone_csv
from rig.bench.scenes import render_scene_to
from rig.bench.reconstruct import reconstruct_session

# Two inserted frames (inner tube 5 and 45 mm out of the outer one) and a rotated one.
FRAMES = (0, 9, 15)
BACKGROUND_FRAMES = 8


@pytest.fixture(scope="module")
def run(paper_scene, tmp_path_factory):
    scene = replace(paper_scene.with_frames([paper_scene.joints[i] for i in FRAMES]), background_frames=BACKGROUND_FRAMES)
    root = tmp_path_factory.mktemp("e2e")
    session = render_scene_to(scene, root / "session", quiet=True)
    return reconstruct_session(session, root / "out", method="paper"), root / "out"


@pytest.fixture(scope="module")
def summary(run):
    return run[0]


def test_every_frame_reconstructed(summary):
    assert summary["frames"] == len(FRAMES)
    assert summary["failed_frames"] == 0, [r["reason"] for r in summary["per_frame"] if r["status"] != "ok"]
    assert summary["scored_frames"] == len(FRAMES)


def test_errors_within_the_voxel(summary):
    for r in summary["per_frame"]:
        voxel = np.asarray(r["voxel_size_mm"])
        edge = float(voxel.max())  # the largest edge of the (anisotropic) voxel
        diagonal = float(np.linalg.norm(voxel))
        assert 0.0 < edge < 2.0
        assert r["mean_error_mm"] <= edge, r
        assert r["tip_error_mm"] <= 2.0 * diagonal, r


def test_outputs_written(run):
    summary, out = run
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["failed_frames"] == 0 and on_disk["voxel_edge_mm_median"] == pytest.approx(summary["voxel_edge_mm_median"])
    table = list(csv.DictReader((out / "frames.csv").open()))
    assert [int(t["frame"]) for t in table] == [r["frame"] for r in summary["per_frame"]]
    assert [t["status"] for t in table] == [r["status"] for r in summary["per_frame"]]
    assert [float(t["t_s"]) for t in table] == pytest.approx([r["t_s"] for r in summary["per_frame"]])
    for r in summary["per_frame"]:
        path = out / "frames" / f"{r['frame']:06d}.csv"
        assert path.read_text().splitlines()[0] == "s_mm,x_mm,y_mm,z_mm,tx,ty,tz"
        rows = np.loadtxt(path, delimiter=",", skiprows=1)
        s, pts, tangent = rows[:, 0], rows[:, 1:4], rows[:, 4:7]
        assert pts.shape == (r["n_points"], 3)
        np.testing.assert_allclose(pts, read_backbone_csv(path))
        assert s[0] == 0.0 and np.all(np.diff(s) > 0) and s[-1] == pytest.approx(r["length_mm"], abs=0.01)
        np.testing.assert_allclose(np.linalg.norm(tangent, axis=1), 1.0, atol=1e-5)
        assert np.all(np.einsum("ij,ij->i", tangent[1:], np.diff(pts, axis=0)) > 0)  # along the curve, base to tip
        # Base first: the backbone starts where the robot leaves the actuation unit (world origin).
        assert np.linalg.norm(pts[0]) <= 2.0 * np.linalg.norm(r["voxel_size_mm"])
