"""``ctr-bench dataset``: sharded files for learned methods, read back without ctr-bench (issue 17 item 4).

A 2-scene wide dataset at 320x240 (the smallest sensor drawn, at half scale) in
shards of 4 samples: 6 samples, scene 1 straddling both shards, built on the Dask sweep's
in-process cluster. It must read back
with json, numpy and PIL alone (docs/dataset.md's snippet runs in a fresh
interpreter that imports no ctr-bench module), its labels must agree with the
truth's projected centerlines, and a re-run must skip the finished shards.
"""
from __future__ import annotations

import json
import pickle
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import rig.bench.render_cache as render_cache
import rig.bench.dataset as dataset
from rig.cli import main

ROOT = Path(__file__).resolve().parents[1]
N, SEED, K = 2, 5, 4
#: The smallest sensor drawn (640x480), rendered at half scale: 320x240.
OPTS = ["--n", N, "--seed", SEED, "--max-megapixels", "0.31", "--scale", "0.5", "--quiet"]
#: The tests that watch this process (a patched renderer or writer) build without a cluster; the fixture's
#: build runs on the default in-process Dask cluster, and the resumed build must give its samples.
HERE = ["--workers", 0]


def _cli(*argv) -> int:
    return main([str(a) for a in argv])


def _no_render(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("rendered although the scene is cached")

    monkeypatch.setattr(render_cache, "render_scene_to", fail)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("dataset")
    out, cache = root / "out" / "wide-dataset", root / "cache"
    assert _cli("dataset", *OPTS, "--shard-size", K, "--out", out, "--cache-dir", cache) == 0
    return root, out, cache


# ----------------------------------------------------------------------------- reading: json, numpy, PIL only
def _rows(out: Path) -> list:
    return [json.loads(line) for line in (out / "index.jsonl").read_text().splitlines()]


def _read(out: Path, row: dict) -> dict:
    arrays = dict(np.load(out / row["arrays"]))
    meta = json.loads((out / row["meta"]).read_text())
    images = {c: np.asarray(Image.open(out / row["images"][c])) for c in row["cameras"]}
    labels = {c: np.asarray(Image.open(out / row["labels"][c])) for c in row["cameras"]}
    return {"arrays": arrays, "meta": meta, "images": images, "labels": labels}


def test_index_shards_and_files(built):
    _, out, _ = built
    meta = json.loads((out / "dataset.json").read_text())
    rows = _rows(out)
    assert meta["format"] == "ctr-bench-dataset" and meta["complete"] and meta["samples"] == len(rows) == 6
    assert [r["sample"] for r in rows] == list(range(6))
    assert meta["shards"] == [{"name": "shard-00000", "samples": 4}, {"name": "shard-00001", "samples": 2}]
    for shard in meta["shards"]:  # each shard's own index: its samples, in order
        own = [json.loads(line) for line in (out / shard["name"] / "index.jsonl").read_text().splitlines()]
        assert [r["shard"] for r in own] == [shard["name"]] * shard["samples"]
        assert own == [r for r in rows if r["shard"] == shard["name"]]
    scenes = json.loads((out / "scenes" / "index.json").read_text())
    assert [s["name"] for s in scenes] == [f"wide-{SEED}-{k}" for k in range(N)]
    assert [r["scene"] for r in rows] == [scenes[0]["name"]] * 3 + [scenes[1]["name"]] * 3  # 3 frame pairs a scene
    assert [r["frame"] for r in rows] == [0, 1, 2, 0, 1, 2]
    for r in rows:
        assert {"backdrop", "base", "tubes", "input", "camera_angle", "resolution", "contrast", "tube_px"} <= r["classes"].keys()
        assert r["classes"] == {**scenes[r["scene"] == scenes[1]["name"]]["classes"], "tube_px": r["classes"]["tube_px"]}
        s = _read(out, r)
        assert r["n_tubes"] == int(r["classes"]["tubes"]) == len(s["arrays"]["extension_mm"])
        for cam in r["cameras"]:
            w, h = r["image_size"][cam]
            assert (w, h) == (320, 240)
            assert s["images"][cam].shape[:2] == s["labels"][cam].shape == (h, w) and s["images"][cam].dtype == np.uint8
            assert s["images"][cam].ndim == (3 if r["color"] == "rgb" else 2)
            assert set(np.unique(s["labels"][cam])) <= set(range(r["n_tubes"] + 1))
            cal = s["meta"]["calibration"]["cameras"][cam]
            assert (cal["width"], cal["height"]) == (w, h)
            assert np.array_equal(np.asarray(cal["K"]), s["arrays"][f"K_{cam}"])
            assert np.array_equal(np.asarray(s["meta"]["T_cam_world_true"][cam]), s["arrays"][f"T_cam_world_true_{cam}"])
        bb = s["arrays"]["backbone_world_mm"]
        assert bb.ndim == 2 and bb.shape[1] == 3 and np.allclose(bb[-1], s["arrays"]["tip_world_mm"])


def test_labels_agree_with_the_truth_centerlines(built):
    import cv2

    _, out, _ = built
    for r in _rows(out):
        s = _read(out, r)
        a = s["arrays"]
        for cam in r["cameras"]:
            uv = a[f"centerline_px_{cam}"]
            # the centerline is the backbone projected through the true pose with OpenCV's model (docs/dataset.md)
            T, cal = a[f"T_cam_world_true_{cam}"], s["meta"]["calibration"]["cameras"][cam]
            p, _ = cv2.projectPoints(a["backbone_world_mm"], cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], np.asarray(cal["K"]),
                                     np.asarray(cal["dist"]))
            assert np.abs(p.reshape(-1, 2) - uv).max() < 1e-6
            w, h = r["image_size"][cam]
            px = np.rint(uv).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
            assert inside.mean() > 0.5, (r["id"], cam)
            lab = s["labels"][cam][px[inside, 1], px[inside, 0]]
            assert (lab > 0).mean() >= 0.98, (r["id"], cam, (lab > 0).mean())  # centerline pixels are tube
            assert (lab == 1 + a["outermost_tube"][inside]).mean() >= 0.9  # ...of the tube outermost there


def test_labels_are_the_truths(built):
    """The label PNGs hold the session's truth labels exactly (the only part of these tests that reads with ctr-bench)."""
    from rig.bench.render_cache import cached_session
    from rig.session import Session
    from twin.scene import load_scene

    _, out, cache = built
    for r in _rows(out)[::3]:
        scene = load_scene(out / "scenes" / f"{r['scene']}.toml")
        session = Session(cached_session(scene, 0.5, cache / "sessions"))
        truth = session.truth(r["frame"])
        s = _read(out, r)
        for cam in r["cameras"]:
            assert np.array_equal(s["labels"][cam], truth[f"labels_{cam}"])
            assert np.array_equal(s["arrays"][f"centerline_px_{cam}"], truth[f"centerline_px_{cam}"])
            assert s["images"][cam].tobytes() == np.asarray(Image.open(session.frame_path(r["frame"], cam))).tobytes()


def test_the_documented_snippet_reads_it_without_ctr_bench(built):
    root, out, _ = built
    text = (ROOT / "docs" / "dataset.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    assert '"out/wide-dataset"' in code and len(code.strip().splitlines()) <= 14
    check = ("\nimport sys\nloaded = sorted(m for m in sys.modules if m.split('.')[0] in ('rig', 'recon', 'twin'))\n"
             "assert not loaded, loaded\nprint('read', len(rows), 'samples')\n")
    proc = subprocess.run([sys.executable, "-I", "-c", code + check], cwd=root, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("read 6 samples"), proc.stdout


# ----------------------------------------------------------------------------- re-runs
def _mtimes(out: Path) -> dict:
    return {p.relative_to(out): p.stat().st_mtime_ns for p in out.rglob("shard-*/*")}


def test_a_rerun_skips_finished_shards(built, monkeypatch, capsys):
    _, out, cache = built
    before, rows = _mtimes(out), _rows(out)
    _no_render(monkeypatch)
    assert _cli("dataset", *OPTS, "--shard-size", K, "--out", out, "--cache-dir", cache, *HERE) == 0
    assert "resuming: 2 of 2 shards finished (skipped), 0 scene(s) to write" in capsys.readouterr().err
    assert _mtimes(out) == before and _rows(out) == rows


def test_an_interrupted_build_resumes_where_it_stopped(built, tmp_path, monkeypatch, capsys):
    _, out1, cache = built
    out = tmp_path / "ds"
    real = dataset.write_scene
    done = []

    def stop_at_second(task):
        pickle.loads(pickle.dumps(task))  # a task is plain data: a distributed map can ship it
        if done:
            raise KeyboardInterrupt
        done.append(task.scene_file)
        return real(task)

    monkeypatch.setattr(dataset, "write_scene", stop_at_second)
    assert _cli("dataset", *OPTS, "--shard-size", 3, "--out", out, "--cache-dir", cache, *HERE) == 130  # scene 1 interrupted
    assert (out / "shard-00000" / "index.jsonl").exists() and not (out / "shard-00001" / "index.jsonl").exists()
    assert not (out / "index.jsonl").exists() and not json.loads((out / "dataset.json").read_text())["complete"]
    monkeypatch.setattr(dataset, "write_scene", real)
    first = _mtimes(out)
    capsys.readouterr()
    _no_render(monkeypatch)
    assert _cli("dataset", *OPTS, "--shard-size", 3, "--out", out, "--cache-dir", cache, *HERE) == 0
    assert "resuming: 1 of 2 shards finished (skipped), 1 scene(s) to write" in capsys.readouterr().err
    assert all(_mtimes(out)[p] == t for p, t in first.items() if p.parts[0] == "shard-00000")
    rows, rows1 = _rows(out), _rows(out1)
    drop = ("shard", "images", "labels", "arrays", "meta")
    assert [{k: v for k, v in r.items() if k not in drop} for r in rows] == [{k: v for k, v in r.items() if k not in drop} for r in rows1]
    for r, r1 in zip(rows, rows1):  # the same samples as the uninterrupted build, in other shards
        a, b = np.load(out / r["arrays"]), np.load(out1 / r1["arrays"])
        assert a.files == b.files and all(np.array_equal(a[k], b[k]) for k in a.files)
        assert all((out / r["labels"][c]).read_bytes() == (out1 / r1["labels"][c]).read_bytes() for c in r["cameras"])


def test_another_dataset_is_refused_without_overwrite(built, tmp_path, monkeypatch, capsys):
    _, _, cache = built
    out = tmp_path / "ds"
    _no_render(monkeypatch)
    assert _cli("dataset", *OPTS, "--shard-size", 3, "--out", out, "--cache-dir", cache, *HERE) == 0
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert _cli("dataset", *OPTS, "--shard-size", 5, "--out", out, "--cache-dir", cache, *HERE) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"ctr-bench dataset: error: {out}: holds a dataset with shard_size = 3, not 5; --overwrite replaces it, or choose another --out"
    assert _cli("dataset", *OPTS, "--shard-size", 5, "--out", out, "--cache-dir", cache, "--overwrite", *HERE) == 0
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "index.jsonl", "notes.txt", "scenes", "shard-00000", "shard-00001"]
    assert [len((out / s / "index.jsonl").read_text().splitlines()) for s in ("shard-00000", "shard-00001")] == [5, 1]
    other = tmp_path / "other"
    other.mkdir()
    (other / "a.txt").write_text("x")
    assert _cli("dataset", *OPTS, "--out", other, "--cache-dir", cache, *HERE) == 2
    assert f"--out {other}: exists and is not empty" in capsys.readouterr().err
