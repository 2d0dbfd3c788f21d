"""A small fixed wide set, end to end as ``ctr-bench bench --suite wide`` runs it (issue 13).

Four scenes of the wide distribution (seed 21, a seed nothing was tuned on;
sensors up to 0.52 MP so that CI renders them in about a minute), rendered,
reconstructed through ``reconstruct_session`` with the self-check, and
scored in pixel footprints. The bounds are the issue's goals for each method.
"""
from __future__ import annotations

import csv
import shutil

import cv2
import pytest

from rig.bench import widebench

SEED = 21
N_SCENES = 4
MAX_PIXELS = 520_000


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("wide")
    return widebench.run_suite("wide", N_SCENES, SEED, ["paper", "fast"], out / "run", out / "cache", quiet=True,
                               max_pixels=MAX_PIXELS), out / "run"


def test_rows_written_for_every_frame_and_method(report):
    rep, out = report
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert len(rows) == 2 * N_SCENES * 3
    assert {r["method"] for r in rows} == {"paper", "fast"}
    assert (out / "summary.json").exists()
    assert set(rep["classes"]["fast"]) == set(widebench.CLASS_KEYS)


def test_the_worst_frames_are_drawn_for_looking_at(report):
    # Each method's worst frames (by max error) as PNGs in OUT/pictures, read back with OpenCV as a user would.
    rep, out = report
    assert rep["worst"]
    for w in rep["worst"]:
        name = f"pictures/{w['method']}-{w['scene']}-f{w['frame']}.png"
        assert name in rep["pictures"], (name, rep["pictures"])
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100, name
    assert sorted(p.name for p in (out / "pictures").iterdir()) == sorted(p.split("/")[1] for p in rep["pictures"])


def test_a_run_that_cannot_be_read_costs_its_picture_only(report, tmp_path, capsys):
    rep, out = report
    w = rep["worst"][0]
    rows = [w, dict(w, scene="wide-21-99")]  # the second names a run that is not there
    shutil.copytree(out / "runs", tmp_path / "runs")
    assert widebench.write_pictures(tmp_path, rows) == [f"pictures/{w['method']}-{w['scene']}-f{w['frame']}.png"]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{w['method']}-wide-21-99-f{w['frame']}.png: not drawn"), err


@pytest.mark.parametrize("method", ["paper", "fast"])
def test_no_silent_wrong_shape(report, method):
    a = report[0]["methods"][method]
    assert a["silent_wrong"] == 0, report[0]["worst"]


def test_fast_meets_its_pixel_bounds(report):
    """Over the frames it reconstructs: mean error <= 1 px at the median and <= 2 px at p95, tip <= 3 px."""
    a = report[0]["methods"]["fast"]
    assert a["mean_error_px_median"] <= 1.0, a
    assert a["mean_error_px_p95"] <= 2.0, a
    assert a["tip_error_px_median"] <= 3.0, a


def test_fast_reconstructs_95_percent(report):
    """12 of 12 frames since d29ad76 (the second tries kept only where they help); wide-21-3 frame 1 was refused."""
    a = report[0]["methods"]["fast"]
    assert a["reconstructed_fraction"] >= 0.95, a


@pytest.mark.xfail(strict=True, reason="issue 13, open: 10 of 12 frames reconstructed (83 %): wide-21-3 frames 0 and 1 "
                   "are refused as 'in pieces the backbone cannot join' (a faint tube of 3.2-3.4 px the silhouette breaks up); "
                   "wide-21-1, its base on the side view's border, is reconstructed since round 41")
def test_paper_within_a_voxel(report):
    a = report[0]["methods"]["paper"]
    assert a["reconstructed_fraction"] >= 0.9, a
    assert a["mean_error_voxels_median"] <= 1.0, a
