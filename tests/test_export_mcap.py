"""``ctr-bench export RUN --mcap FILE`` (issue 14): read back with the mcap reader, every message decoded."""
from __future__ import annotations

import collections

import numpy as np
import pytest

from synthetic_run import make_run_dir

def _read(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = collections.defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out[channel.topic].append((schema.name, message.log_time, decoded))
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return make_run_dir(tmp_path_factory.mktemp("mcap"))


def test_export_round_trip(run_dir, tmp_path):
    import json

    from recon.rigcal import load_rig_calibration
    from rig.bench.mcap_export import export_mcap

    out = tmp_path / "run.mcap"
    counts = export_mcap(run_dir, out)
    msgs = _read(out)
    rig = load_rig_calibration(run_dir / "session" / "rig.json")
    topics = {"/tf", "/ctr/backbone", "/ctr/tube"} | {f"/{n}/{k}" for n in rig.names for k in ("camera_info", "image/compressed")}
    assert set(msgs) == topics
    assert all(len(v) == 3 for v in msgs.values()) and counts == {t: 3 for t in topics}
    records = json.loads((run_dir / "summary.json").read_text())["per_frame"]
    with np.load(run_dir / "backbones.npz") as z:
        for k, rec in enumerate(records):
            t_ns = int(round(rec["t_s"] * 1e9))
            name, log_time, path = msgs["/ctr/backbone"][k]
            assert name == "nav_msgs/msg/Path" and log_time == t_ns and path.header.frame_id == "world"
            marker = msgs["/ctr/tube"][k][2]
            if rec["status"] == "failed":
                assert path.poses == [] and marker.action == 3  # DELETEALL: nothing drawn for a failed frame
                continue
            got = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses])
            np.testing.assert_allclose(got, z[f"frame_{rec['frame']:06d}"] / 1000.0, atol=1e-12)  # metres
            assert marker.type == 4 and marker.action == 0 and len(marker.points) == len(got)
            assert marker.scale.x == pytest.approx(2 * 0.8 / 1000.0)
            # Each pose's x axis along the curve.
            q = path.poses[len(got) // 2].pose.orientation
            from scipy.spatial.transform import Rotation

            x_axis = Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([1.0, 0.0, 0.0])
            tangent = np.gradient(got, axis=0)[len(got) // 2]
            assert x_axis @ tangent / np.linalg.norm(tangent) > 0.999
    for n in rig.names:
        info = msgs[f"/{n}/camera_info"][0][2]
        np.testing.assert_allclose(np.reshape(info.k, (3, 3)), rig[n].K)
        assert info.distortion_model == "plumb_bob" and np.allclose(info.d, rig[n].dist[:5])
        R = np.reshape(info.r, (3, 3))
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-9  # the rectifying rotation
        assert (info.width, info.height) == (rig[n].width, rig[n].height) and info.header.frame_id == f"{n}_optical"
        for k in range(3):
            img = msgs[f"/{n}/image/compressed"][k][2]
            assert img.format == "png" and bytes(img.data) == (run_dir / "session" / "frames" / n / f"{k:06d}.png").read_bytes()
        tf = {t.child_frame_id: t.transform for t in msgs["/tf"][0][2].transforms}
        tr = tf[f"{n}_optical"].translation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], rig[n].center_world_mm / 1000.0, atol=1e-12)
    # the second camera's P carries -f' * baseline (m) in Tx or Ty, the first camera 0, as ROS stereo expects
    B_m = np.linalg.norm(rig["side"].center_world_mm - rig["top"].center_world_mm) / 1000.0
    P = {n: np.reshape(msgs[f"/{n}/camera_info"][0][2].p, (3, 4)) for n in ("side", "top")}
    t = sorted(float((p[0, 3] + p[1, 3]) / p[0, 0]) for p in P.values())
    assert abs(t[0] + B_m) < 1e-9 and t[1] == 0.0
    base = tf["robot_base"].translation
    np.testing.assert_allclose([base.x, base.y, base.z], rig.base_point_world_mm / 1000.0, atol=1e-12)


def test_cli_export_and_its_errors(run_dir, tmp_path, capsys):
    from rig.cli import main

    assert main(["export", str(run_dir), "--mcap", str(tmp_path / "a.mcap"), "--quiet"]) == 0
    assert "mcap: " in capsys.readouterr().out
    for argv, expect in (
        ([str(run_dir), "--mcap", str(tmp_path / "a.bag")], "must end in .mcap"),
        ([str(run_dir), "--mcap", str(tmp_path / "no" / "a.mcap")], "does not exist"),
        ([str(tmp_path), "--mcap", str(tmp_path / "b.mcap")], "no summary.json"),
    ):
        assert main(["export", *argv, "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expect in err, err


def test_export_without_its_session_says_so(tmp_path):
    from rig.bench.mcap_export import export_mcap

    bare = make_run_dir(tmp_path, with_session=False)
    with pytest.raises(ValueError, match="session"):
        export_mcap(bare, tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()
