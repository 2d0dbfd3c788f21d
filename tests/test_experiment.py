"""One experiment, twin or rig: cameras, rig files, sequences and the experiment runner.

* the twin experiment's live reconstruction equals ``ctr-bench reconstruct`` of its session;
* a run killed with SIGKILL keeps every frame committed before the kill;
* the same sequence file runs on the twin actuator and on the Arduino firmware in the
  emulator (rig/hw/sim) -- only the rig file differs;
* the OpenCV backend reads a video file; the replay backend replays a session;
* rig-file and sequence-file errors name the file and the key;
* CameraPair measures the skew between the cameras and frames.csv records it.

Measured figures are printed at the end of the module (pytest -s / -rA).
"""
from __future__ import annotations

import csv
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

try:                                    # tests/ as a package or as a rootdir
    from .fil_fixtures import *  # noqa: F401,F403
except ImportError:
    from fil_fixtures import *  # noqa: F401,F403

from figures import record

from rig.cli import main as cli
from rig.hw.actuator import JointValues, SoftLimits
from rig.hw.camera import Camera, CameraError, CameraPair, EndOfStream, OpenCVCamera
from rig.hw.experiment import ExperimentRunner, SequenceError, load_sequence
from rig.hw.rigfile import RigFileError, load_rig_file, rig_file_from_dict
from rig.hw.virtual import Trapezoid, TwinActuator
from rig.rundir import JOURNAL, read_journal, read_run
from rig.scenefiles import scenes_dir
from rig.session import Session

ROOT = Path(__file__).resolve().parents[1]
SCENES = scenes_dir()
SCENE = SCENES / "paper.toml"


def _report(key, value):
    """A measured figure, printed in the terminal summary (tests/figures.py)."""
    record("experiment", key, value)


# A short sequence: the structure of scenes/paper-sequence.toml with few frames.
SEQUENCE = """
format = "ctr-bench-sequence"
version = 1
name = "short"

[settings]
settle_timeout_s = 15.0
home_timeout_s = 30.0

[[steps]]
kind = "home"

[[steps]]
kind = "background"
frames = 6
retract = { insertion_mm = 0.0 }

[[steps]]
kind = "move"
to = { insertion_mm = 10.0, rotation_deg = 0.0 }

[[steps]]
kind = "grab"

[[steps]]
kind = "repeat"
times = 2

  [[steps.steps]]
  kind = "move"
  by = { insertion_mm = 10.0 }

  [[steps.steps]]
  kind = "dwell"
  seconds = 0.05

  [[steps.steps]]
  kind = "grab"

[[steps]]
kind = "move"
by = { rotation_deg = 45.0 }

[[steps]]
kind = "grab"
"""
#: insertion / rotation at each grab of SEQUENCE
EXPECTED = [(10.0, 0.0), (20.0, 0.0), (30.0, 0.0), (30.0, 45.0)]

RIG_COMMON = f"""
format = "ctr-bench-rig"
version = 1
scene = "{SCENE}"

[joints]
home_extension_mm = [50.0, 55.0]
home_rotation_deg = [0.0, 0.0]

[cameras]
kind = "twin"
timeout_s = 60.0
"""
LIMITS = """
[actuator.limits]
insertion_mm = [0.0, 50.0]
rotation_deg = [-180.0, 180.0]
"""
RIG_TWIN = RIG_COMMON + """
[actuator]
kind = "twin"
time_scale = 4.0
start = { insertion_mm = 1.5, rotation_deg = 0.0 }
""" + LIMITS
RIG_ARDUINO = RIG_COMMON + """
[actuator]
kind = "arduino"
port = "/dev/null/not-a-port"       # given with --serial
""" + LIMITS


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _rows(session_dir: Path) -> list:
    with open(session_dir / "frames.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("exp-files")
    return {
        "seq": _write(d / "short-sequence.toml", SEQUENCE),
        "twin": _write(d / "rig-twin.toml", RIG_TWIN),
        "arduino": _write(d / "rig-twin-arduino.toml", RIG_ARDUINO),
        "dir": d,
    }


@pytest.fixture(scope="module")
def twin_session(files, tmp_path_factory):
    """The short sequence on the twin rig, reconstructed live with the paper's method."""
    out = tmp_path_factory.mktemp("exp-twin") / "session"
    t = time.monotonic()
    rc = cli(["experiment", str(files["seq"]), "--rig", str(files["twin"]), "--out", str(out),
              "--reconstruct", "paper"])
    wall = time.monotonic() - t
    assert rc == 0
    _report("twin experiment wall time (6 background + 4 frame pairs, live paper)", f"{wall:.1f} s")
    return out


# ============================================================================ experiment on the twin
def test_live_reconstruction_equals_replay(twin_session, tmp_path, capsys):
    s = Session(twin_session)
    assert len(s.frames) == len(EXPECTED) and s.meta["background_frames"] == 6
    assert s.has_truth and s.meta["source"] == "twin"
    for fr, (ins, rot) in zip(s.frames, EXPECTED):
        assert fr.extension_mm == pytest.approx((50.0, 55.0 + ins))
        assert fr.rotation_deg == pytest.approx((0.0, rot))
    rec = tmp_path / "rec"
    assert cli(["reconstruct", str(twin_session), "--out", str(rec), "--quiet"]) == 0
    live = np.load(twin_session / "live" / "backbones.npz")
    offline = np.load(rec / "backbones.npz")
    assert sorted(live.files) == sorted(offline.files)
    assert list(live["frames"]) == list(range(len(EXPECTED)))
    for k in live.files:
        assert np.array_equal(live[k], offline[k]), k          # identical, not just close
    for i in range(len(EXPECTED)):                              # and the per-frame CSVs byte for byte
        a = (twin_session / "live" / "frames" / f"{i:06d}.csv").read_bytes()
        assert a == (rec / "frames" / f"{i:06d}.csv").read_bytes()


def test_a_live_frame_the_method_doubts_is_suspect(files, tmp_path, monkeypatch, capsys):
    """No self-check runs live, but a frame the method itself cannot vouch for (its ``suspect_reason``)
    is recorded ``suspect`` with that reason, never ``ok``, and the closing line counts it."""
    import dataclasses
    import json

    from recon.methods import METHODS, Method, get_method

    paper = get_method("paper")
    doubt = "the tube folds across an epipolar plane"

    def doubting(rig, background_frames, params):
        inner = paper.prepare(rig, background_frames, params)
        return lambda frames: dataclasses.replace(inner(frames), suspect_reason=doubt)

    monkeypatch.setitem(METHODS, "doubting", Method("doubting", paper.params_type, doubting, "test: doubts every frame"))
    out = tmp_path / "session"
    assert cli(["experiment", str(files["seq"]), "--rig", str(files["twin"]), "--out", str(out), "--reconstruct", "doubting"]) == 0
    records = [json.loads(line) for line in (out / "live" / "frames.jsonl").read_text().splitlines()]
    records = [r for r in records if "frame" in r]
    assert [(r["status"], r["reason"]) for r in records] == [("suspect", doubt)] * len(EXPECTED)
    assert f"{len(EXPECTED)}/{len(EXPECTED)} frames reconstructed ({len(EXPECTED)} suspect)" in capsys.readouterr().out


def test_live_directory_is_a_run_directory_scored_as_reconstruct_scores(twin_session, tmp_path):
    """live/ is written by the run writer (journal, table, summary with run id) and scored over what both cameras see."""
    live = twin_session / "live"
    summary, backbones = read_run(live)
    assert summary["complete"] and summary["run_id"] and sorted(backbones) == list(range(len(EXPECTED)))
    header, records = read_journal(live / JOURNAL)
    assert header["run_id"] == summary["run_id"] and header["method"] == "paper" and len(records) == len(EXPECTED)
    assert (live / "frames.csv").exists()
    rec = tmp_path / "rec"
    assert cli(["reconstruct", str(twin_session), "--out", str(rec), "--quiet", "--no-report"]) == 0
    offline, _ = read_run(rec)
    keys = ("mean_error_mm", "max_error_mm", "tip_error_mm", "length_error_mm", "scored_fraction")
    for a, b in zip(summary["per_frame"], offline["per_frame"]):
        assert a["mean_error_mm"] is not None
        assert {k: a[k] for k in keys} == {k: b[k] for k in keys}, a["frame"]   # the same figures, not just close


def test_skew_measured_and_recorded(twin_session):
    rows = _rows(twin_session)
    skews = [float(r["skew_ms"]) for r in rows]
    for r in rows:
        ts = [float(r["t_side_s"]), float(r["t_top_s"])]
        assert float(r["skew_ms"]) == pytest.approx(abs(ts[0] - ts[1]) * 1e3, abs=2e-3)
        assert float(r["t_s"]) > 0
    assert max(skews) < 50.0                       # two worker threads started together
    import json

    events = [json.loads(line) for line in (twin_session / "experiment.jsonl").read_text().splitlines()]
    frames = [e for e in events if e["event"] == "frame"]
    end = events[-1]
    assert end["event"] == "end" and end["frames"] == len(EXPECTED)
    _report("twin pair skew (ms)", f"median {statistics.median(skews):.3f}, max {max(skews):.3f}")
    _report("twin per-frame grab (render) ms", f"median {end['grab_ms_median']:.0f}, max {end['grab_ms_max']:.0f}")
    _report("twin frame cycle ms (move+dwell+grab+write+recon)", f"median {end['cycle_ms_median']:.0f}")
    _report("twin live paper reconstruction ms", f"median {end['recon_ms_median']:.0f}")
    assert len(frames) == len(EXPECTED)


def test_sigkill_keeps_committed_frames(files, tmp_path):
    seq = _write(tmp_path / "long.toml", SEQUENCE.replace("times = 2", "times = 4").replace(
        "insertion_mm = 10.0 }\n\n  [[steps.steps]]", "insertion_mm = 5.0 }\n\n  [[steps.steps]]"))
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    exe = [sys.executable, "-m", "rig.cli", "experiment", str(seq), "--rig", str(files["twin"]), "--out", str(out)]
    proc = subprocess.Popen(exe, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    k = 2
    deadline = time.monotonic() + 90
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "frames.csv").exists() and len(_rows(out)) >= k:
                break
            time.sleep(0.02)
        assert proc.poll() is None, f"experiment ended before the kill: {proc.stderr.read().decode()[-2000:]}"
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    s = Session(out)                                    # readable after SIGKILL
    n = len(s.frames)
    assert k <= n < 7
    for fr in s.frames:
        imgs = s.frame_images(fr.index)
        assert set(imgs) == {"side", "top"} and imgs["side"].shape == (768, 1024)
        assert s.truth(fr.index) is not None
    from rig.bench.reconstruct import reconstruct_session

    summary = reconstruct_session(out, tmp_path / "rec", method="paper")
    assert summary["frames"] == n and summary["failed_frames"] < n
    _report("SIGKILL", f"killed after {k} committed frames; {n} readable and reconstructed")


def _replay_rig_file(tmp_path, session):
    """A rig file replaying ``session`` (cameras and actuator log)."""
    return _write(tmp_path / "replay.toml", f"""
format = "ctr-bench-rig"
version = 1
[joints]
home_extension_mm = [50.0, 55.0]
[cameras]
kind = "replay"
session = "{session}"
[actuator]
kind = "replay"
""")


def test_interrupt_stops_actuator_and_keeps_frames(twin_session, tmp_path):
    """Ctrl-C (KeyboardInterrupt) mid-experiment: motors stopped, frames kept. On a replay rig (fast)."""
    rig_file = _replay_rig_file(tmp_path, twin_session)
    spec = load_rig_file(rig_file)
    seq = load_sequence(_write(tmp_path / "s.toml", SEQUENCE))
    stopped = []

    def interrupt(index, pair, joints, result):
        if index == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with spec.open() as rig:
            orig = rig.actuator.stop
            rig.actuator.stop = lambda: (stopped.append(True), orig())[1]
            ExperimentRunner(rig, seq, tmp_path / "out", log=lambda s: None, on_frame=interrupt).run()
    assert stopped, "leaving the rig block must stop the actuator"
    s = Session(tmp_path / "out")
    assert [f.index for f in s.frames] == [0, 1]


# ============================================================================ same sequence, arduino
def test_same_sequence_on_arduino_emulator(files, twin_session, sim_factory, tmp_path):
    h = sim_factory("--x0-mm", "1.5")
    out = tmp_path / "arduino"
    t = time.monotonic()
    rc = cli(["experiment", str(files["seq"]), "--rig", str(files["arduino"]), "--serial", h.pty,
              "--out", str(out), "--reconstruct", "paper"])
    wall = time.monotonic() - t
    assert rc == 0
    _report("arduino-emulator experiment wall time (same sequence)", f"{wall:.1f} s")
    a, b = Session(twin_session), Session(out)
    assert b.meta["actuator_backend"] == "arduino" and a.meta["actuator_backend"] == "twin"
    assert a.meta["sequence_file"] == b.meta["sequence_file"]
    assert len(b.frames) == len(a.frames) == len(EXPECTED)
    for fa, fb in zip(a.frames, b.frames):                  # measured joints: the firmware's tolerance
        assert fb.extension_mm == pytest.approx(fa.extension_mm, abs=0.05)
        assert fb.rotation_deg == pytest.approx(fa.rotation_deg, abs=0.5)
    import json

    summary = json.loads((out / "live" / "summary.json").read_text())
    assert summary["frames"] == len(EXPECTED) and summary["failed_frames"] < len(EXPECTED)
    # the emulator's clock channel: how often it waited for a late host (ctr_sim's exit line)
    h.close()
    q = h.wait_event("Q", timeout_s=5)
    stats = dict(f.split("=", 1) for f in q.fields if "=" in f)
    _report("arduino-emulator clock channel", ", ".join(f"{k} {stats.get(k)}" for k in (
        "leases", "lease_waits", "max_lease_wait_ms", "forced_leases", "max_lag_ms")))
    assert int(stats["leases"]) > 0, "the driver did not lease the emulator's time (no clock channel)"


# ============================================================================ opencv, replay, pair
def _video(path: Path, n: int, size=(64, 48)) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, size)
    assert w.isOpened()
    for i in range(n):
        img = np.full((size[1], size[0], 3), 10 + 20 * i, np.uint8)
        img[5:15, 5:15] = (0, 0, 255)                       # red square: BGR input -> mono output
        w.write(img)
    w.release()
    return path


def test_opencv_backend_reads_video_file(tmp_path):
    path = _video(tmp_path / "clip.avi", 5)
    with OpenCVCamera("side", str(path), timeout_s=5.0) as cam:
        assert not cam.needs_operator                      # a file, not a live camera
        levels = []
        for i in range(5):
            f = cam.grab()
            assert f.image.dtype == np.uint8 and f.image.shape == (48, 64) and f.seq == i and f.camera == "side"
            levels.append(float(np.median(f.image)))
        assert levels == sorted(levels) and levels[-1] - levels[0] > 60      # in order
        with pytest.raises(EndOfStream, match="side"):
            cam.grab()
    with OpenCVCamera("top", str(path), loop=True) as cam:
        assert len([cam.grab() for _ in range(7)]) == 7
    with pytest.raises(CameraError, match="'side'.*not found"):
        OpenCVCamera("side", str(tmp_path / "missing.avi")).open()
    # a pair of video files through CameraPair
    pair = CameraPair([OpenCVCamera("side", str(path)), OpenCVCamera("top", str(_video(tmp_path / "b.avi", 3)))])
    with pair:
        fp = pair.grab()
        assert set(fp.images) == {"side", "top"} and fp.skew_ms >= 0


def test_opencv_rig_file_experiment(tmp_path):
    """An opencv rig (video files) + twin actuator: the experiment code path of the lab rig."""
    from recon.camera import Camera as CalCamera
    from recon.rigcal import RigCalibration, save_rig_calibration

    K = [[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]]
    save_rig_calibration(tmp_path / "rig.json", RigCalibration(
        {n: CalCamera(n, 64, 48, K) for n in ("side", "top")}))
    _video(tmp_path / "side.avi", 8)
    _video(tmp_path / "top.avi", 8)
    rig_file = _write(tmp_path / "rig-video.toml", """
format = "ctr-bench-rig"
version = 1
calibration = "rig.json"
[joints]
home_extension_mm = [50.0, 55.0]
[cameras]
kind = "opencv"
[cameras.side]
source = "side.avi"
[cameras.top]
source = "top.avi"
[actuator]
kind = "twin"
time_scale = 20.0
""")
    seq = _write(tmp_path / "seq.toml", SEQUENCE)
    out = tmp_path / "out"
    assert cli(["experiment", str(seq), "--rig", str(rig_file), "--out", str(out), "--quiet"]) == 0
    s = Session(out)
    assert s.meta["source"] == "rig" and s.meta["camera_backend"] == "opencv"
    assert len(s.frames) == 2 and s.meta["background_frames"] == 6     # 8 frames per file: replay ended
    # The videos were recorded beforehand: the twin actuator's 50/75 mm would be invented joints.
    assert all(f.extension_mm is None and f.rotation_deg is None for f in s.frames)
    assert "video files" in s.meta["joints_not_recorded"]
    rows = _rows(out)
    assert rows and all(r["extension_1_mm"] == "" and r["rotation_1_deg"] == "" for r in rows)


def test_replay_backend_replays_session(twin_session, tmp_path):
    rig_file = _replay_rig_file(tmp_path, twin_session)
    out = tmp_path / "again"
    assert cli(["experiment", str(_write(tmp_path / "s.toml", SEQUENCE)), "--rig", str(rig_file),
                "--out", str(out), "--reconstruct", "paper", "--quiet"]) == 0
    a, b = Session(twin_session), Session(out)
    assert [f.extension_mm for f in a.frames] == [f.extension_mm for f in b.frames]
    assert [f.rotation_deg for f in a.frames] == [f.rotation_deg for f in b.frames]
    for f in a.frames:
        for cam in ("side", "top"):
            assert np.array_equal(a.frame_images(f.index)[cam], b.frame_images(f.index)[cam])
    la = np.load(twin_session / "live" / "backbones.npz")
    lb = np.load(out / "live" / "backbones.npz")
    assert all(np.array_equal(la[k], lb[k]) for k in la.files)


class _SlowCamera(Camera):
    """A camera whose exposure takes ``delay_s`` (to measure skew and timeouts)."""

    def __init__(self, name, delay_s, timeout_s=1.0):
        super().__init__(name, timeout_s)
        self.delay_s = delay_s

    def _open(self):
        pass

    def _close(self):
        pass

    def _trigger(self):
        time.sleep(self.delay_s)

    def _retrieve(self):
        return np.zeros((4, 6), np.uint8)


def test_camera_pair_skew_and_timeouts():
    # The delay is long against the scheduling jitter of the two worker threads (tens of ms on a
    # loaded machine: a 30 ms delay once measured 18 ms with two busy processes on two cores).
    with CameraPair([_SlowCamera("side", 0.0), _SlowCamera("top", 0.25)]) as pair:
        skews = [pair.grab().skew_ms for _ in range(3)]
    assert all(150.0 <= s <= 450.0 for s in skews), skews     # the 250 ms delay shows as skew
    with CameraPair([_SlowCamera("side", 0.0), _SlowCamera("top", 0.0)]) as pair:
        fp = pair.grab()
        assert fp.skew_ms < 100.0 and fp.frames["top"].wall_time_s > 1e9
    cam = _SlowCamera("top", 2.0, timeout_s=0.2).open()
    t = time.monotonic()
    with pytest.raises(TimeoutError, match="camera 'top'"):
        cam.grab()
    assert time.monotonic() - t < 1.0
    with pytest.raises(CameraError, match="'top'.*hung"):
        cam.grab()
    cam.close()


# ============================================================================ twin actuator
def test_twin_actuator_profile_and_limits():
    act = TwinActuator(SoftLimits((0.0, 40.0), (-90.0, 90.0)), time_scale=20.0,
                       start=JointValues(2.0, 30.0))
    with pytest.raises(Exception, match="not homed"):
        act.move_to({"insertion_mm": 5.0, "rotation_deg": 0.0})
    act.home(timeout_s=5)
    assert act.position() == JointValues(0.0, 0.0)            # rotation: current angle becomes 0
    assert act.true_position().rotation_deg == pytest.approx(30.0)
    with pytest.raises(ValueError, match="insertion_mm=50"):
        act.move_to({"insertion_mm": 50.0})
    act.move_to({"insertion_mm": 30.0, "rotation_deg": 45.0})
    mid = act.position()
    assert 0.0 <= mid.insertion_mm < 30.0                     # still moving
    t = time.monotonic()
    pos = act.wait_settled(5)
    # 30 mm at 15 mm/s, 195 mm/s^2: 2.08 s simulated = 0.10 s at time_scale 20
    assert 0.03 < time.monotonic() - t < 0.5
    assert pos == JointValues(30.0, 45.0)
    act.move_to({"insertion_mm": 0.0})
    with pytest.raises(TimeoutError, match="insertion_mm"):
        act.wait_settled(0.01)
    act.stop()
    assert act.target is None
    tr = Trapezoid(0.0, 0.0, 10.0, 15.0, 195.0)
    assert tr.at(tr.duration) == 10.0 and tr.at(tr.duration / 2) == pytest.approx(5.0)


# ============================================================================ file errors
def test_rig_file_errors_name_file_and_key(tmp_path):
    def err(text, match):
        p = _write(tmp_path / "bad-rig.toml", text)
        with pytest.raises(RigFileError) as ei:
            load_rig_file(p)
        assert str(p) in str(ei.value), ei.value
        assert match in str(ei.value), ei.value

    good_head = f'format = "ctr-bench-rig"\nscene = "{SCENE}"\n'
    err(good_head + '[cameras]\nkind = "webcam"\n[actuator]\nkind = "twin"\n', "cameras.kind: must be one of")
    err(good_head + '[cameras]\nkind = "twin"\n[actuator]\nkind = "twin"\nspeed = 3\n', "actuator.speed: unknown key")
    err(good_head + '[cameras]\nkind = "twin"\n[actuator]\nkind = "twin"\n[actuator.limits]\ninsertion_mm = [5, 1]\n',
        "actuator.limits.insertion_mm")
    err(good_head + '[cameras]\nkind = "twin"\n[actuator]\nkind = "twin"\nmax_velocity = { insertion_mm = -1 }\n',
        "actuator.max_velocity.insertion_mm: must be > 0")
    err('format = "ctr-bench-rig"\ncalibration = "c.json"\n[joints]\nhome_extension_mm = [1.0, 2.0]\n'
        '[cameras]\nkind = "opencv"\n[cameras.side]\nsource = 0\n[cameras.top]\nsorce = 1\n[actuator]\nkind = "twin"\n',
        "cameras.top.source: missing")
    err('format = "ctr-bench-rig"\n[joints]\nhome_extension_mm = [1.0, 2.0]\n[cameras]\nkind = "opencv"\n'
        '[cameras.side]\nsource = 0\n[cameras.top]\nsource = 1\n[actuator]\nkind = "twin"\n', "calibration: missing")
    err(good_head + '[cameras]\nkind = "twin"\n[actuator]\nkind = "arduino"\nport = 3\n', "actuator.port: must be a string")
    err(good_head + '[cameras]\nkind = "twin"\n', "actuator: missing table")
    err('format = "ctr-bench-rig"\nscene = "nope.toml"\n[cameras]\nkind = "twin"\n[actuator]\nkind = "twin"\n',
        "scene: ")
    err(good_head + '[cameras]\nkind = "twin"\n[actuator]\nkind = "twin"\n[joints]\nhome_extension_mm = [1.0]\n',
        "joints.home_extension_mm: 1 values")
    err("this is = not toml [", "not valid TOML")
    # --serial only for an arduino actuator
    with pytest.raises(RigFileError, match="actuator.kind: --serial"):
        load_rig_file(SCENES / "rig-twin.toml", serial="/dev/pts/9")
    # a calibration whose cameras are not the rig's
    with pytest.raises(RigFileError, match="calibration"):
        rig_file_from_dict({"format": "ctr-bench-rig", "scene": str(SCENE), "calibration": str(tmp_path / "none.json"),
                            "cameras": {"kind": "twin"}, "actuator": {"kind": "twin"}},
                           str(tmp_path / "r.toml")).load_calibration()


def test_sequence_errors_name_file_and_key(tmp_path):
    def err(text, match, limits=None):
        p = _write(tmp_path / "bad-seq.toml", text)
        with pytest.raises(SequenceError) as ei:
            seq = load_sequence(p)
            if limits is not None:
                from rig.hw.experiment import check_limits

                check_limits(seq, limits)
        assert str(p) in str(ei.value) and match in str(ei.value), ei.value

    err('[[steps]]\nkind = "jump"\n', "steps[0].kind: must be one of")
    err('[[steps]]\nkind = "move"\n', "steps[0].to: give exactly one")
    err('[[steps]]\nkind = "move"\nto = { insertion_mm = 1.0 }\nby = { insertion_mm = 1.0 }\n', "steps[0].to")
    err('[[steps]]\nkind = "move"\nto = { insertin_mm = 1.0 }\n', "steps[0].to.insertin_mm: unknown key")
    err('[[steps]]\nkind = "dwell"\n', "steps[0].seconds: missing")
    err('[[steps]]\nkind = "repeat"\ntimes = 2\n', "steps[0].steps")
    err('[[steps]]\nkind = "repeat"\ntimes = 2\n[[steps.steps]]\nkind = "grab"\npairs = 0\n', "steps[0].steps[0].pairs")
    err("", "steps: at least one")
    err('[[steps]]\nkind = "home"\n[[steps]]\nkind = "repeat"\ntimes = 5\n[[steps.steps]]\nkind = "move"\n'
        'by = { insertion_mm = 15.0 }\n', "steps[1].steps[0].by: insertion_mm would be 60 (steps[1] 4/5)",
        limits=SoftLimits((0.0, 50.0), (-90.0, 90.0)))
    # the CLI prints it as one line naming the file
    seq = load_sequence(SCENES / "paper-sequence.toml")
    assert seq.grab_count == 20 and seq.background_count >= 6


def test_example_files_load():
    """The shipped rig files and the paper sequence are valid (the lab rig needs no hardware to load)."""
    twin = load_rig_file(SCENES / "rig-twin.toml")
    ard = load_rig_file(SCENES / "rig-twin-arduino.toml", serial="/dev/pts/5")
    lab = load_rig_file(SCENES / "rig-lab.toml")
    assert twin.cameras["kind"] == "twin" and twin.actuator["kind"] == "twin"
    assert ard.actuator["port"] == "/dev/pts/5"
    assert lab.cameras["kind"] == "opencv" and "dc1394src" in lab.cameras["per_camera"]["side"]["source"]
    assert lab.actuator["port"] == "/dev/ttyACM0"
    seq = load_sequence(SCENES / "paper-sequence.toml")
    from rig.hw.experiment import check_limits, grab_targets

    for spec in (twin, ard, lab):
        check_limits(seq, spec.limits)
    # the paper sequence on the twin rig visits exactly the joints of scenes/paper.toml
    from twin.scene import load_scene

    scene = load_scene(SCENE)
    grabs = [twin.joint_map.to_joints(JointValues(**t)) for t in grab_targets(seq)]
    assert len(grabs) == len(scene.joints)
    for g, j in zip(grabs, scene.joints):
        assert g.extension_mm == pytest.approx(j.extension_mm) and g.rotation_deg == pytest.approx(j.rotation_deg)


def test_dry_run(capsys):
    assert cli(["experiment", str(SCENES / "paper-sequence.toml"), "--rig",
                str(SCENES / "rig-lab.toml"), "--out", "/nonexistent/never", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "20 frame pairs" in out and "opencv" in out

