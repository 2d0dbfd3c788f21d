"""``ctr-bench run`` renders a scene once (issue 17 item 3).

The render cache (rig/bench/render_cache.py) that bench, tune and dataset use keeps the
session under a hash of the scene file's content: a second ``run`` of the same
scene renders nothing, and its results are those of the first. ``--no-cache``
renders afresh without touching the cache.
"""
from __future__ import annotations

import contextlib
import io
import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

import rig.bench.render_cache as render_cache
import rig.cli.commands.run as run_cmd
from rig.cli import main
from rig.bench.render_cache import cache_key
from twin.scene import load_scene

from conftest import SCENES

#: The cheapest run of the paper scene the paper method accepts.
ARGS = ["--n-frames", "2", "--n-background-frames", "6", "--no-report", "--quiet"]
#: Per-frame keys that are timings (they differ from run to run, nothing else may).
TIMINGS = ("ms", "timings_ms")


def _cli(*argv) -> int:
    return main([str(a) for a in argv])


def _results(out):
    summary = json.loads((out / "summary.json").read_text())
    frames = []
    for rec in summary["per_frame"]:
        rec = {k: v for k, v in rec.items() if k not in TIMINGS}
        if isinstance(rec.get("selfcheck"), dict):
            rec["selfcheck"] = {k: v for k, v in rec["selfcheck"].items() if k != "ms"}
        frames.append(rec)
    with np.load(out / "backbones.npz") as z:
        backbones = {k: z[k] for k in z.files}
    return frames, backbones


def _no_render(monkeypatch):
    """Any render from here on fails the test (the cache's and run's own)."""
    def fail(*a, **k):
        raise AssertionError("rendered although the scene is cached")

    monkeypatch.setattr(render_cache, "render_scene_to", fail)
    monkeypatch.setattr(run_cmd, "render_scene_to", fail)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """One run of the paper scene into an empty cache: it renders."""
    root = tmp_path_factory.mktemp("run-cache")
    cache, out = root / "cache", root / "run1"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert _cli("run", SCENES / "paper.toml", *ARGS, "--out", out, "--cache-dir", cache) == 0
    return root, cache, out, buf.getvalue()


def test_second_run_takes_the_render_from_the_cache(first_run, monkeypatch, capsys):
    root, cache, out1, text1 = first_run
    assert "rendering 'paper'" in text1 and "(cached for later runs)" in text1
    (cached,) = [p for p in cache.iterdir() if p.is_dir()]
    _no_render(monkeypatch)
    out2 = root / "run2"
    assert _cli("run", SCENES / "paper.toml", *ARGS, "--out", out2, "--cache-dir", cache) == 0
    text2 = capsys.readouterr().out
    assert f"reusing the render of 'paper' (2 frames, 6 background frames) cached in {cached}" in text2
    assert "session from the cache in" in text2 and ", from the cache)" in text2
    # identical results: every backbone, every per-frame figure but the timings
    frames1, bb1 = _results(out1)
    frames2, bb2 = _results(out2)
    assert frames1 == frames2 and len(frames1) == 2
    assert bb1.keys() == bb2.keys() and all(np.array_equal(bb1[k], bb2[k]) for k in bb1)
    # OUT/session shares the cached files (hard links on one file system), bytes for bytes
    a, b = cached / "frames" / "side" / "000000.png", out2 / "session" / "frames" / "side" / "000000.png"
    assert a.read_bytes() == b.read_bytes() and a.stat().st_ino == b.stat().st_ino
    # --overwrite removes the run's own session, not the cache it was linked from
    assert _cli("run", SCENES / "paper.toml", *ARGS, "--out", out2, "--cache-dir", cache, "--overwrite") == 0
    assert "reusing the render" in capsys.readouterr().out
    assert a.exists() and _results(out2)[0] == frames1


def test_another_copy_of_the_scene_file_shares_the_render(first_run, tmp_path, monkeypatch, capsys):
    _, cache, _, _ = first_run
    copy = tmp_path / "elsewhere.toml"
    shutil.copyfile(SCENES / "paper.toml", copy)
    _no_render(monkeypatch)
    assert _cli("run", copy, *ARGS, "--out", tmp_path / "r", "--cache-dir", cache) == 0
    assert "reusing the render" in capsys.readouterr().out
    # this run's session names this run's scene file (its own session.json; the cache's is unchanged)
    assert json.loads((tmp_path / "r" / "session" / "session.json").read_text())["scene"] == str(copy)


def test_no_cache_renders_afresh_and_leaves_the_cache_alone(first_run, tmp_path, monkeypatch, capsys):
    _, cache, _, _ = first_run
    before = sorted(p.relative_to(cache) for p in cache.rglob("*"))
    calls = []
    real = run_cmd.render_scene_to
    monkeypatch.setattr(run_cmd, "render_scene_to", lambda *a, **k: (calls.append(a[1]), real(*a, **k))[1])
    out = tmp_path / "fresh"
    assert _cli("run", SCENES / "paper.toml", *ARGS, "--out", out, "--cache-dir", cache, "--no-cache") == 0
    assert calls == [out / "session"] and f"into {out / 'session'}" in capsys.readouterr().out
    assert sorted(p.relative_to(cache) for p in cache.rglob("*")) == before


def test_the_key_is_the_scene_content(tmp_path):
    scene = load_scene(SCENES / "paper.toml")
    copy = tmp_path / "copy.toml"
    shutil.copyfile(SCENES / "paper.toml", copy)
    assert cache_key(load_scene(copy)) == cache_key(scene)  # the content, not the path
    changed = tmp_path / "changed.toml"
    changed.write_text((SCENES / "paper.toml").read_text() + "\n# another scene\n")
    assert cache_key(load_scene(changed)) != cache_key(scene)
    assert cache_key(scene.with_frames(scene.joints[:2])) != cache_key(scene)
    assert cache_key(replace(scene, background_frames=6)) != cache_key(scene)
    assert cache_key(replace(scene, model="compliant" if scene.model == "bending" else "bending")) != cache_key(scene)
    assert cache_key(scene, 0.5) != cache_key(scene)
