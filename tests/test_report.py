"""The run report (rig/bench/report.py), tube meshes (recon/tubemesh.py, rig/bench/meshes.py) and the live view's fallback (rig/live.py).

The run directories here are synthetic (tests/synthetic_run.py), so these tests do not
depend on any reconstruction method.
"""
from __future__ import annotations

import io
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from synthetic_run import make_run_dir

from recon.metrics import point_to_polyline_distances
from recon.tubemesh import clean_polyline, radii_along, tangents, transport_frames, tube_mesh

@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A synthetic run directory with its report (and meshes) built once."""
    from rig.bench.report import build_report

    out = make_run_dir(tmp_path_factory.mktemp("report"))
    build_report(out, meshes=True)
    return out


def _local_links(html: str) -> list:
    return [l for l in re.findall(r"(?:src|href)='([^']+)'", html) if not l.startswith(("#", "http:", "https:"))]


# ------------------------------------------------------------------------ report
def test_report_builds_with_valid_images(run_dir):
    index = run_dir / "report" / "index.html"
    html = index.read_text()
    assert "<script" not in html.lower()
    pngs = [l for l in _local_links(html) if l.endswith(".png")]
    expected = {"backbones_3d.png", "projections.png", "error_along_arc.png", "errors_per_frame.png", "timing.png",
                "tubes.png", "tubes_over_time.png", "frames/000000.png", "frames/000001.png", "frames/000002.png"}
    assert expected <= set(pngs)
    for link in _local_links(html):
        path = (index.parent / link).resolve()
        assert path.is_file() and path.stat().st_size > 0, link
        if link.endswith(".png"):
            with Image.open(path) as im:
                im.verify()
            with Image.open(path) as im:
                assert im.format == "PNG" and im.size[0] > 100 and im.size[1] > 100
                assert np.asarray(im.convert("L")).std() > 1.0, f"{link} is blank"
    # the failed frame and its reason are listed; the summary numbers are in the table
    assert "no robot silhouette found (synthetic)" in html
    assert "1.100 mm" in html and "85.0" in html
    # its overlay still shows the truth (and says why the frame failed)
    assert "frames/000002.png" in pngs


def test_overlay_marks_reconstruction_and_truth(run_dir):
    from rig.bench.report import RECON_RGB, TRUTH_RGB

    img = np.asarray(Image.open(run_dir / "report" / "frames" / "000001.png").convert("RGB")).astype(int)
    for rgb in (RECON_RGB, TRUTH_RGB):
        close = np.abs(img - np.array(rgb)).sum(axis=2) < 30
        assert close.sum() > 200, f"colour {rgb} hardly drawn"


def test_a_header_wider_than_the_panels_is_drawn_smaller_not_cut(tmp_path):
    # A failed frame's header (status, three errors with px, time) ran off the right edge of a 915 px wide picture.
    from rig.bench.report import overlay_panels

    img = np.full((120, 160), 128, np.uint8)
    uv = np.array([[20.0, 60.0], [140.0, 60.0]])
    header = "frame 2  ·  SUSPECT  ·  " + "  ·  ".join(f"error {k} 29.99 mm (77.8 px)" for k in range(2))
    path = overlay_panels(tmp_path / "o.png", {"side": img}, {"side": uv}, {"side": uv}, header, view_width=320)
    strip = np.asarray(Image.open(path).convert("L"))[:28]
    assert strip[:, :-6].min() < 100  # the header is there
    assert strip[:, -6:].min() > 200  # and ends before the edge


def test_meshes_written_and_load_back(run_dir):
    mdir = run_dir / "meshes"
    for f in (0, 1):
        for name in (f"{f:06d}.ply", f"{f:06d}.obj"):
            m = trimesh.load(mdir / name, force="mesh", process=False)
            assert len(m.faces) > 100
            assert m.is_watertight
            pts = np.loadtxt(run_dir / "frames" / f"{f:06d}.csv", delimiter=",", skiprows=1)
            assert np.all(m.bounds[0] > pts.min(axis=0) - 0.81) and np.all(m.bounds[1] < pts.max(axis=0) + 0.81)
        scene = trimesh.load(mdir / f"{f:06d}.glb")
        assert sum(len(g.faces) for g in scene.geometry.values()) > 100
        both = trimesh.load(mdir / f"{f:06d}_both.glb")
        assert set(both.geometry) == {"reconstruction", "truth"}
    assert not (mdir / "000002.ply").exists()  # failed frame: nothing to mesh
    html = (run_dir / "report" / "index.html").read_text()
    assert "../meshes/000000.glb" in html


def test_cli_rebuilds_and_runs_without_session(tmp_path, capsys):
    from rig.cli import main

    # outputs whose session is gone: figures only, and a note says why
    bare = make_run_dir(tmp_path, with_session=False)
    stale = bare / "report" / "stale.png"
    stale.parent.mkdir()
    stale.write_bytes(b"x")
    assert main(["report", str(bare), "--no-meshes", "--quiet"]) == 0
    assert "report:" in capsys.readouterr().out
    assert not stale.exists()
    html = (bare / "report" / "index.html").read_text()
    assert "session directory was not found" in html and "backbones_3d.png" in html
    for link in _local_links(html):
        assert (bare / "report" / link).resolve().is_file(), link
    assert not (bare / "meshes").exists()


@pytest.mark.parametrize("spoil", ["corrupt", "two_columns"])
def test_a_bad_truth_file_is_a_note_not_the_end_of_the_report(tmp_path, spoil):
    # One corrupt or malformed truth npz used to stop the whole report with a traceback.
    from rig.bench.report import build_report

    out = make_run_dir(tmp_path)
    bad = out / "session" / "truth" / "000001.npz"
    if spoil == "corrupt":
        bad.write_bytes(b"PK\x03\x04 not a zip archive")
    else:
        with np.load(bad) as z:
            arrays = dict(z)
        np.savez(bad, **{**arrays, "backbone_world_mm": arrays["backbone_world_mm"][:, :2]})
    html = build_report(out, meshes=False).read_text()
    assert "Frame 1 is drawn without ground truth" in html and "000001.npz" in html
    assert "Frame 0 is drawn without" not in html


def test_session_text_is_escaped(tmp_path):
    # Notes, reasons and file names come from a user's session: the template shows them as text, never markup.
    from rig.bench.report import build_report

    out = make_run_dir(tmp_path / "a<b>&'c")
    summary = json.loads((out / "summary.json").read_text())
    r0, r1, r2 = summary["per_frame"]
    r0["note"] = "<script>alert(1)</script>"
    r1.update(status="suspect", reason="<b>bold</b> & more", jump_flag=True, jump_reason="<i>40 mm</i>")
    r2["reason"] = "<img src=x onerror=alert(2)>"
    (out / "summary.json").write_text(json.dumps(summary))
    html = build_report(out, meshes=False, overlays=False).read_text()
    assert "<script" not in html.lower() and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "<b>bold</b>" not in html and "suspect: &lt;b&gt;bold&lt;/b&gt; &amp; more" in html
    assert "<i>" not in html and "(jump: &lt;i&gt;40 mm&lt;/i&gt;)" in html
    assert "<img src=x" not in html and html.count("&lt;img src=x onerror=alert(2)&gt;") == 2  # failed table, frame section
    assert "a<b>" not in html and "a&lt;b&gt;&amp;&#39;c" in html
    # the markup the page means is still markup
    assert "<tr class='suspect'>" in html and "<tr class='failed'>" in html and "<b>1.100 mm</b>" in html


def test_cli_report_errors_are_one_line(tmp_path, capsys):
    from rig.cli import main
    from rig.bench.report import report_or_warn

    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "summary.json" in err and "Traceback" not in err
    assert report_or_warn(tmp_path) is None
    assert "ctr-bench report" in capsys.readouterr().err


def test_run_and_reconstruct_accept_report_options():
    from rig.cli import _parser

    p = _parser()
    a = p.parse_args(["reconstruct", "S", "--out", "O", "--no-report", "--live"])
    assert a.no_report and a.live
    a = p.parse_args(["run", "--no-report"])
    assert a.no_report and not a.live
    a = p.parse_args(["run"])
    assert not a.no_report


def test_detail_frame_selection_keeps_failed_and_worst():
    from rig.bench.report import select_detail_frames

    recs = [{"frame": i, "status": "ok", "mean_error_mm": float(i % 17)} for i in range(200)]
    recs[5] = {"frame": 5, "status": "failed"}
    chosen = select_detail_frames(recs, 30)
    assert len(chosen) <= 30 and 5 in chosen and 16 in chosen and chosen == sorted(chosen)
    assert select_detail_frames(recs[:10], 30) == list(range(10))


# -------------------------------------------------------------------- tube mesh
def _check_mesh(v, f, P, r):
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0  # outward normals
    assert m.euler_number == 2
    return m


def test_tube_mesh_radius_and_normals_on_a_curve():
    t = np.linspace(0, 2.5, 80)
    P = np.stack([30 * np.cos(t), 30 * np.sin(t), 8 * t], axis=1)
    sides = 12
    v, f = tube_mesh(P, 0.8, sides=sides)
    _check_mesh(v, f, P, 0.8)
    rings = v[: len(P) * sides].reshape(len(P), sides, 3)
    T = tangents(P)
    off = rings - P[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(off, axis=2), 0.8, atol=1e-9)  # radius
    assert np.abs(np.einsum("nsk,nk->ns", off, T)).max() < 1e-9  # circles normal to the tangent
    # the tangent is the bisector of the two segments at a point (the direction to the next point at the ends)
    d = np.diff(P, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(T[0], d[0])
    np.testing.assert_allclose(T[-1], d[-1])
    assert np.all(np.einsum("ij,ij->i", T[1:-1], d[1:]) > 0.99)
    # frames: orthonormal, right-handed, hardly twisting
    F = transport_frames(P)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", F, F), np.broadcast_to(np.eye(3), F.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(F), 1.0, atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", F[1:, :, 0], F[:-1, :, 0]) > 0.99)


def test_tube_mesh_straight_vertices_at_radius_from_backbone():
    P = np.stack([np.linspace(0, 50, 26), np.full(26, 3.0), np.full(26, -2.0)], axis=1)
    v, f = tube_mesh(P, 0.5, sides=16)
    _check_mesh(v, f, P, 0.5)
    ring_v = v[:-2]
    np.testing.assert_allclose(point_to_polyline_distances(ring_v, P), 0.5, atol=1e-6)
    # the two cap centres are the end points
    np.testing.assert_allclose(v[-2:], P[[0, -1]])


def test_tube_mesh_radii_per_point_and_degenerate_input():
    P = np.stack([np.linspace(0, 40, 41), np.zeros(41), np.zeros(41)], axis=1)
    r = radii_along(P[:, 0], 20.0, 0.8, 0.5)
    assert r[0] == 0.8 and r[-1] == 0.5 and r[20] == 0.8 and r[21] == 0.5
    v, f = tube_mesh(P, r, sides=8)
    rings = v[:-2].reshape(41, 8, 3)
    np.testing.assert_allclose(np.linalg.norm(rings - P[:, None], axis=2), r[:, None].repeat(8, 1), atol=1e-9)
    assert np.all(radii_along([0, 10], None, 0.8, 0.5) == 0.8)
    # repeated points are dropped, not turned into a broken ring
    Pd = np.concatenate([P[:5], P[4:5], P[5:]])
    v2, f2 = tube_mesh(Pd, 0.8, sides=8)
    assert len(v2) == len(tube_mesh(P, 0.8, sides=8)[0])
    assert len(clean_polyline(Pd)) == len(P)
    with pytest.raises(ValueError):
        tube_mesh(P[:1], 0.8)
    with pytest.raises(ValueError):
        tube_mesh(P, -1.0)
    with pytest.raises(ValueError):
        tube_mesh(P, [0.8, 0.5])


def test_mesh_exports_round_trip(tmp_path):
    from rig.bench.meshes import write_frame_meshes

    t = np.linspace(0, 1, 40)
    P = np.stack([50 * t, 10 * t**2, np.zeros_like(t)], axis=1)
    truth = {"backbone_world_mm": np.stack([60 * t, 12 * t**2, 0 * t], axis=1), "outer_radius_mm": np.where(t < 0.5, 0.8, 0.5)}
    paths = write_frame_meshes(tmp_path, 7, P, 20.0, truth)
    names = sorted(p.name for p in paths)
    assert names == ["000007.glb", "000007.obj", "000007.ply", "000007_both.glb"]
    ref = trimesh.Trimesh(*tube_mesh(P, radii_along(np.r_[0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))], 20.0, 0.8, 0.5), sides=16), process=False)
    for name in ("000007.ply", "000007.obj"):
        m = trimesh.load(tmp_path / name, force="mesh", process=False)
        assert len(m.vertices) == len(ref.vertices) and len(m.faces) == len(ref.faces)
        np.testing.assert_allclose(m.bounds, ref.bounds, atol=1e-4)
        assert m.is_watertight
    g = trimesh.load(tmp_path / "000007.glb", force="mesh")
    np.testing.assert_allclose(g.bounds, ref.bounds, atol=1e-4)
    truth_mesh = trimesh.load(tmp_path / "000007_both.glb").geometry["truth"]
    assert truth_mesh.is_watertight
    # it ends at the true tip, with the inner tube's radius there
    d = np.linalg.norm(truth_mesh.vertices - truth["backbone_world_mm"][-1], axis=1)
    np.testing.assert_allclose(np.sort(d)[1:17], 0.5, atol=1e-4)  # cap centre, then the last circle


# ------------------------------------------------------------------- live view
def test_live_without_rerun_says_so_and_stays_out_of_the_way(monkeypatch):
    from rig import live

    monkeypatch.setitem(sys.modules, "rerun", None)  # "import rerun" raises ImportError
    assert live.import_rerun() is None
    msg = io.StringIO()
    logger = live.LiveLogger(stream=msg)
    assert not logger.enabled
    text = msg.getvalue()
    assert text.count("\n") == 1 and "rerun-sdk is not installed" in text
    progress = object()
    assert logger.watch("session", "out", progress) is progress
    prepared = logger.log_frame(3, 1.5, backbone_mm=np.zeros((4, 3)))
    assert prepared["frame"] == 3 and prepared["entries"][0][0] == "world/reconstruction"


def test_live_prepare_frame_and_emit():
    from types import SimpleNamespace

    from rig import live

    img = np.zeros((6, 8), np.uint8)
    recon = np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 0, 0], [2, 0, 0]])
    p = live.prepare_frame(4, 2.0, images={"side": img, "top": img}, backbone_mm=recon, truth_mm=np.ones((5, 3)),
                           errors={"mean_error_mm": 0.3, "tip_error_mm": None}, recon_uv={"side": np.array([[1.0, 2], [np.inf, 0]])},
                           truth_uv={"top": np.array([[1.0, 2], [3, 4]])}, status="failed", reason="no silhouette")
    kinds = {path: (kind, data) for path, kind, data, _ in p["entries"]}
    assert kinds["cameras/side/image"][0] == "image" and kinds["cameras/top/image"][1].dtype == np.uint8
    assert kinds["cameras/side/reconstruction"][1].shape == (1, 2)  # the non-finite point is dropped
    assert kinds["cameras/top/truth"][1].shape == (2, 2)
    assert "cameras/side/truth" not in kinds and "cameras/top/reconstruction" not in kinds
    assert kinds["world/reconstruction"][1].shape == (3, 3) and kinds["world/reconstruction"][1].dtype == np.float32
    assert kinds["world/truth"][0] == "line3d"
    assert kinds["errors/mean_error_mm"] == ("scalar", 0.3) and "errors/tip_error_mm" not in kinds
    assert "no silhouette" in kinds["log"][1]

    calls = []
    fake = SimpleNamespace(
        init=lambda *a, **k: calls.append(("init", a)),
        set_time=lambda name, **k: calls.append(("time", name, k)),
        log=lambda path, obj: calls.append(("log", path, obj)),
        Image=lambda d: ("Image", d.shape), LineStrips2D=lambda s, colors: ("L2", len(s[0])),
        LineStrips3D=lambda s, colors: ("L3", len(s[0])), Scalars=lambda v: ("S", v), TextLog=lambda t: ("T", t))
    logger = live.LiveLogger(rr=fake)
    assert logger.enabled
    logger.emit(p)
    logged = {c[1]: c[2] for c in calls if c[0] == "log"}
    assert logged["world/reconstruction"] == ("L3", 3) and logged["errors/mean_error_mm"] == ("S", 0.3)
    assert ("time", "frame", {"sequence": 4}) in calls
