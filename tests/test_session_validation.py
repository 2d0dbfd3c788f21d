"""Reading a session directory (rig/session.py, rig/session_checks.py): every bad input is one line naming the file.

The sessions here are tiny and synthetic (32x24 images written with the session
writer), so no rendering is needed: a template is written once per module and
copied for each test that spoils it.
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from recon.rigcal import RigCalibration
from rig.session import FrameRecord, Session, SessionError, TruthError, read_image
from rig.session_checks import MAX_TUBES, frame_columns
from tiny_session import H, N_POINTS, W, tiny_backbone, write_tiny_session

N_FRAMES = 3
LONG = os.environ.get("HYPOTHESIS_PROFILE") == "long"


def _truth(rig: RigCalibration, f: int) -> dict:
    bb = tiny_backbone(f)
    s = np.linspace(0.0, 40.0 + f, N_POINTS)
    out = {"s_mm": s, "backbone_world_mm": bb, "tip_world_mm": bb[-1], "extension_mm": np.array([30.0, 40.0 + f]),
           "rotation_deg": np.array([0.0, 10.0 * f])}
    for c in rig.names:
        out[f"T_cam_world_{c}"] = rig[c].T_cam_world
        out[f"labels_{c}"] = np.zeros((H, W), np.uint8)
        out[f"centerline_px_{c}"] = rig[c].project(bb)[0]
    return out


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A valid session: 2 cameras, 2 tubes, 6 background pairs, 3 frames with joints and ground truth."""
    return write_tiny_session(tmp_path_factory.mktemp("template") / "session", N_FRAMES, _truth)


@pytest.fixture
def session(template, tmp_path) -> Path:
    """A fresh copy of the template, to spoil."""
    d = tmp_path / "session"
    shutil.copytree(template, d)
    return d


def _error(d: Path, **kw) -> str:
    """The one-line SessionError message of opening ``d``."""
    with pytest.raises(SessionError) as err:
        Session(d, **kw)
    msg = str(err.value)
    assert "\n" not in msg, msg
    return msg


def _csv_lines(d: Path) -> list:
    return (d / "frames.csv").read_text().splitlines()


def _write_csv(d: Path, lines: list, end: str = "\r\n") -> None:
    (d / "frames.csv").write_text("\r\n".join(lines) + end)


def _edit_meta(d: Path, **changes) -> None:
    meta = json.loads((d / "session.json").read_text())
    meta.update(changes)
    (d / "session.json").write_text(json.dumps(meta))


# ----------------------------------------------------------------------------- a valid session

def test_the_template_reads_back(template):
    s = Session(template)
    assert [f.index for f in s.frames] == [0, 1, 2] and s.notes == []
    assert s.cameras == ["side", "top"] and s.n_tubes == 2 and s.image_size == (W, H)
    assert s.frames[2] == FrameRecord(2, pytest.approx(0.2), 0.0, (30.0, 42.0), (0.0, 20.0))
    assert s.robot_tube_radii_mm == (0.8, 0.5)
    t = s.truth(1)
    assert t["backbone_world_mm"].shape == (N_POINTS, 3)


def test_frames_without_joints_and_a_bom_are_fine(session):
    lines = _csv_lines(session)
    _write_csv(session, [lines[0]] + [",".join(ln.split(",")[:5] + [""] * 4) for ln in lines[1:]])
    (session / "session.json").write_bytes(b"\xef\xbb\xbf" + (session / "session.json").read_bytes())
    s = Session(session)
    assert len(s.frames) == N_FRAMES and all(f.extension_mm is None and f.rotation_deg is None for f in s.frames)


# ----------------------------------------------------------------------------- frames.csv

def _field(lines: list, row: int, col: str, value: str) -> list:
    """``lines`` with ``col`` of data row ``row`` (0 = first frame) set to ``value``."""
    header = lines[0].split(",")
    fields = lines[1 + row].split(",")
    fields[header.index(col)] = value
    return lines[: 1 + row] + [",".join(fields)] + lines[2 + row :]


def _drop_column(lines: list, col: str) -> list:
    i = lines[0].split(",").index(col)
    return [",".join(f for j, f in enumerate(ln.split(",")) if j != i) for ln in lines]


BAD_CSV = {
    "middle row too short": (lambda ls: ls[:2] + [ls[2].rsplit(",", 2)[0]] + ls[3:], r":3: 7 fields, the header has 9$"),
    "middle row too long": (lambda ls: ls[:2] + [ls[2] + ",1"] + ls[3:], r":3: 10 fields, the header has 9$"),
    "sed 3a hello,world": (lambda ls: ls[:3] + ["hello,world"] + ls[3:], r":4: 2 fields, the header has 9$"),
    "extra field in row 1": (lambda ls: ls[:1] + [ls[1] + ",7"] + ls[2:], r":2: 10 fields, the header has 9$"),
    "empty middle line": (lambda ls: ls[:2] + [""] + ls[2:], r":3: 1 fields, the header has 9 \(an empty line\)$"),
    "non-numeric index": (lambda ls: _field(ls, 1, "frame", "x"), r":3: frame must be an integer >= 0, got 'x'$"),
    "negative index": (lambda ls: _field(ls, 1, "frame", "-1"), r":3: frame must be an integer >= 0, got '-1'$"),
    "fractional index": (lambda ls: _field(ls, 0, "frame", "0.5"), r":2: frame must be an integer >= 0, got '0.5'$"),
    "non-numeric time": (lambda ls: _field(ls, 1, "t_s", "soon"), r":3: t_s must be a finite number, got 'soon'$"),
    "NaN time": (lambda ls: _field(ls, 2, "t_s", "nan"), r":4: t_s must be a finite number, got 'nan'$"),
    "inf time": (lambda ls: _field(ls, 0, "t_s", "inf"), r":2: t_s must be a finite number, got 'inf'$"),
    "overflowing time": (lambda ls: _field(ls, 0, "t_s", "1e400"), r":2: t_s must be a finite number, got '1e400'$"),
    "NaN camera time": (lambda ls: _field(ls, 0, "t_top_s", "nan"), r":2: t_top_s must be a finite number, got 'nan'$"),
    "inf joint": (lambda ls: _field(ls, 1, "rotation_1_deg", "-inf"), r":3: rotation_1_deg must be a finite number, got '-inf'$"),
    "joints partly empty": (lambda ls: _field(ls, 1, "extension_1_mm", ""),
                            r":3: joint values partly empty \(extension_1_mm is empty, extension_0_mm is not\)$"),
    "missing header column": (lambda ls: _drop_column(ls, "skew_ms"), r":1: missing column 'skew_ms' \(cameras side, top, n_tubes 2"),
    "missing camera column": (lambda ls: _drop_column(ls, "t_top_s"), r":1: missing column 't_top_s'"),
    "unknown column": (lambda ls: [ln + ",0" for ln in ls], r":1: unexpected column '0'"),
    "column twice": (lambda ls: [ls[0].replace("skew_ms", "t_s")] + ls[1:], r":1: column 't_s' appears twice$"),
    "duplicate frame index": (lambda ls: _field(ls, 2, "frame", "1"), r":4: frame 1 repeats line 3$"),
    "empty file": (lambda ls: [], r": empty \(no header row\)$"),
}


@pytest.mark.parametrize("case", list(BAD_CSV))
def test_malformed_frames_csv_is_one_line_naming_file_and_line(session, case):
    spoil, expect = BAD_CSV[case]
    _write_csv(session, spoil(_csv_lines(session)))
    msg = _error(session)
    assert msg.startswith(f"{session / 'frames.csv'}:"), msg
    assert re.search(expect, msg), msg


@pytest.mark.parametrize("cut", ["fewer fields", "mid-field, no line end", "complete but no line end", "then a blank line"])
def test_only_a_last_row_cut_short_is_forgiven_and_noted(session, cut):
    text = (session / "frames.csv").read_text()
    last = text.rstrip("\r\n").rsplit("\n", 1)[1]
    head = text[: len(text.rstrip("\r\n")) - len(last)]
    spoilt = {"fewer fields": ",".join(last.split(",")[:4]) + "\r\n", "mid-field, no line end": last[:-3],
              "complete but no line end": last, "then a blank line": ",".join(last.split(",")[:6]) + "\r\n\r\n"}[cut]
    (session / "frames.csv").write_text(head + spoilt)
    s = Session(session)
    assert [f.index for f in s.frames] == [0, 1]
    assert len(s.notes) == 1 and s.notes[0].startswith(f"{session / 'frames.csv'}:4: last row cut short (")
    assert "\n" not in s.notes[0]


def test_binary_frames_csv_is_not_a_text_file(session):
    (session / "frames.csv").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe garbage")
    assert _error(session) == f"{session / 'frames.csv'}: not a text file (byte 0x89 at offset 0 is not UTF-8)"
    (session / "frames.csv").write_bytes(b"frame,t_s\x00\x00\r\n")
    assert _error(session) == f"{session / 'frames.csv'}: not a text file (NUL byte at offset 9)"


def test_a_session_without_frames_says_so(session):
    _write_csv(session, _csv_lines(session)[:1])
    assert _error(session) == f"{session / 'frames.csv'}: no committed frames, nothing to reconstruct"
    assert Session(session, allow_empty=True).frames == []
    _write_csv(session, _csv_lines(session)[:1] + ["0,0.0"], end="")
    assert _error(session).startswith(f"{session / 'frames.csv'}: no committed frames, nothing to reconstruct "
                                      f"({session / 'frames.csv'}:2: last row cut short (2 of 9 fields)")


def test_frames_csv_missing(session):
    (session / "frames.csv").unlink()
    assert _error(session) == f"{session / 'frames.csv'}: missing"


# ----------------------------------------------------------------------------- session.json

BAD_META = {
    "a list": ([1, 2], r": must be a JSON object, got list \[1, 2\]$"),
    "n_tubes a word": ({"n_tubes": "two"}, r"session.json: n_tubes must be an integer from 0 to \d+, got 'two'$"),
    "n_tubes huge": ({"n_tubes": 1000}, r": n_tubes must be an integer from 0 to \d+, got 1000$"),
    "n_tubes bool": ({"n_tubes": True}, r": n_tubes must be an integer from 0 to \d+, got True$"),
    "n_tubes NaN": ({"n_tubes": math.nan}, r": n_tubes must be an integer from 0 to \d+, got nan$"),
    "n_tubes other than the csv's": ({"n_tubes": 1}, r"frames.csv:1: unexpected column 'extension_1_mm' \(cameras side, top, n_tubes 1"),
    "cameras a string": ({"cameras": "side"}, r": cameras must be a list of camera names, got 'side'$"),
    "cameras of numbers": ({"cameras": [1, 2]}, r": cameras must be a list of camera names, got \[1, 2\]$"),
    "cameras empty": ({"cameras": []}, r": cameras must name at least one camera, got \[\]$"),
    "camera renamed": ({"cameras": ["side", "left"]}, r": cameras: 'left' is not in .*rig.json \(it calibrates side, top\)$"),
    "camera missing": ({"cameras": ["side"]}, r": cameras lacks 'top', which .*rig.json calibrates$"),
    "camera twice": ({"cameras": ["side", "side", "top"]}, r": cameras: 'side' is listed twice$"),
    "camera a path": ({"cameras": ["../side", "top"]}, r": cameras\[0\]: '../side' is not a camera name"),
    "image_size a word": ({"image_size": "big"}, r": image_size must be \[width, height\] in pixels .*, got 'big'$"),
    "image_size negative": ({"image_size": [32, -24]}, r": image_size must be .*, got \[32, -24\]$"),
    "ground_truth a word": ({"ground_truth": "yes"}, r": ground_truth must be true or false, got 'yes'$"),
    "background_frames negative": ({"background_frames": -6}, r": background_frames must be an integer >= 0, got -6$"),
    "robot a list": ({"robot": [1]}, r": robot must be an object, got \[1\]$"),
    "robot tubes a dict": ({"robot": {"tubes": {"a": 1}}}, r": robot.tubes must be a list, got \{'a': 1\}$"),
    "tube diameter inf": ({"robot": {"tubes": [{"outer_diameter_mm": math.inf}]}},
                          r": robot.tubes\[0\]: each tube needs a numeric outer_diameter_mm > 0, got inf$"),
    "tube diameter a word": ({"robot": {"tubes": [{"outer_diameter_mm": "1.6"}]}}, r"outer_diameter_mm > 0, got '1.6'$"),
    "wrong format": ({"format": "other"}, r": format is 'other', expected 'ctr-bench-session'$"),
    "newer version": ({"version": 2}, r": version 2 is not supported \(this ctr-bench reads 1\)$"),
    "version true": ({"version": True}, r": version True is not supported"),
}


@pytest.mark.parametrize("case", list(BAD_META))
def test_malformed_session_json_is_one_line_naming_the_key(session, case):
    change, expect = BAD_META[case]
    if isinstance(change, dict):
        _edit_meta(session, **change)
    else:
        (session / "session.json").write_text(json.dumps(change))
    msg = _error(session)
    assert msg.startswith(str(session)), msg
    assert re.search(expect, msg), msg


def test_binary_or_broken_session_json(session):
    path = session / "session.json"
    path.write_bytes(b"\x00\x01\xfa\xfb binary")
    assert _error(session) == f"{path}: not a text file (byte 0xfa at offset 2 is not UTF-8)"
    path.write_text('{"format": "ctr-bench-session",')
    assert _error(session).startswith(f"{path}: not valid JSON (")
    path.unlink()
    assert _error(session) == f"{session}: no session.json (not a ctr-bench session directory)"


def test_a_camera_folder_that_is_missing(session):
    shutil.rmtree(session / "background" / "top")
    assert _error(session) == f"{session / 'session.json'}: cameras: 'top' has no background/top folder"


def test_rig_json_binary_or_malformed_names_the_file(session):
    rig = session / "rig.json"
    rig.write_bytes(b"\xff\xd8\xff\xe0 jpeg")
    assert _error(session) == f"{rig}: not a text file (byte 0xff at offset 0 is not UTF-8)"
    rig.write_text('{"cameras": ["side", "top"]}')
    assert _error(session).startswith(f"{rig}: ")
    rig.unlink()
    assert _error(session) == f"{rig}: rig calibration file not found"


# ----------------------------------------------------------------------------- images

def test_a_frame_path_that_is_a_directory(session):
    path = session / "frames" / "top" / "000001.png"
    path.unlink()
    path.mkdir()
    with pytest.raises(SessionError) as err:
        Session(session).frame_images(1)
    assert str(err.value) == f"{path}: is a directory, not an image file"


@pytest.mark.parametrize("content, expect", [(b"", "unreadable image (not a valid PNG)"),
                                             (b"\x89PNG\r\n\x1a\n truncated", "unreadable image (not a valid PNG)"),
                                             (None, "image file missing")])
def test_unreadable_images_name_the_path(session, content, expect):
    path = session / "frames" / "side" / "000000.png"
    path.unlink()
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(SessionError) as err:
        read_image(path)
    assert str(err.value) == f"{path}: {expect}"


# ----------------------------------------------------------------------------- ground truth

def _spoil_truth(d: Path, index: int, **changes) -> Path:
    path = d / "truth" / f"{index:06d}.npz"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})
    return path


BAD_TRUTH = {
    "(n, 2) backbone": ({"backbone_world_mm": np.zeros((N_POINTS, 2))},
                        f"backbone_world_mm has shape ({N_POINTS}, 2), expected (n={N_POINTS}, 3)"),
    "NaN backbone": ({"backbone_world_mm": np.full((N_POINTS, 3), np.nan)}, "backbone_world_mm holds NaN or inf"),
    "one point": ({"backbone_world_mm": np.zeros((1, 3))}, "backbone_world_mm has 1 point(s), a backbone needs at least 2"),
    "no backbone": ({"backbone_world_mm": None}, "no backbone_world_mm array"),
    "text backbone": ({"backbone_world_mm": np.array([["a", "b", "c"]] * 3)}, "backbone_world_mm has dtype <U1, expected numbers"),
    "short s_mm": ({"s_mm": np.zeros(3)}, f"s_mm has shape (3,), expected (n={N_POINTS},)"),
    "inf tip": ({"tip_world_mm": np.array([0.0, np.inf, 0.0])}, "tip_world_mm holds NaN or inf"),
    "3 joints": ({"extension_mm": np.zeros(3)}, "extension_mm has shape (3,), expected (k=2,)"),
    "labels of another size": ({"labels_top": np.zeros((H, W + 1), np.uint8)},
                               f"labels_top has shape ({H}, {W + 1}), expected (H={H}, W={W})"),
    "pose 3x4": ({"T_cam_world_side": np.eye(4)[:3]}, "T_cam_world_side has shape (3, 4), expected (4, 4)"),
}


@pytest.mark.parametrize("case", list(BAD_TRUTH))
def test_bad_truth_is_a_truth_error_naming_the_file(session, case):
    changes, expect = BAD_TRUTH[case]
    path = _spoil_truth(session, 1, **changes)
    s = Session(session)
    with pytest.raises(TruthError) as err:
        s.truth(1)
    assert str(err.value) == f"{path}: {expect}"
    assert s.truth(0) is not None and s.truth(2) is not None     # the other frames' truth is untouched


def _zip_of_text(path: Path) -> bytes:
    import zipfile

    with zipfile.ZipFile(path, "w") as z:
        z.writestr("backbone_world_mm", "1 2 3")
    return path.read_bytes()


@pytest.mark.parametrize("content", [b"", b"not a zip at all", b"\x93NUMPY\x01\x00 v", "truncated", "zip of text"])
def test_corrupt_truth_npz(session, content):
    path = session / "truth" / "000000.npz"
    data = path.read_bytes()
    if content == "zip of text":
        content = _zip_of_text(path)
    path.write_bytes(data[: len(data) // 2] if content == "truncated" else content)
    s = Session(session)
    with pytest.raises(TruthError) as err:
        s.truth(0)
    msg = str(err.value)
    assert msg.startswith(f"{path}: unreadable ground truth (") and "\n" not in msg, msg
    assert [s.truth(i)["backbone_world_mm"].shape for i in (1, 2)] == [(N_POINTS, 3)] * 2


def test_missing_truth_is_an_error_only_when_the_session_has_truth(session):
    path = session / "truth" / "000002.npz"
    path.unlink()
    with pytest.raises(TruthError) as err:
        Session(session).truth(2)
    assert str(err.value) == f"{path}: missing (session.json says the session has ground truth)"
    _edit_meta(session, ground_truth=False)
    assert Session(session).truth(2) is None
    path.mkdir()
    with pytest.raises(TruthError, match=r"unreadable ground truth \(Is a directory\)$"):
        Session(session).truth(2)


def test_truth_error_is_a_session_error():
    assert issubclass(TruthError, SessionError) and issubclass(SessionError, ValueError)


# ----------------------------------------------------------------------------- fuzz

ODD_VALUES = [None, "two", "side", "", 2, 0, -1, 2.5, 1e300, math.nan, math.inf, -math.inf, True, False, [], {}, [1, 2],
              ["side"], ["side", "top", "front"], ["top", "side"], [None], {"tubes": [{"outer_diameter_mm": math.nan}]},
              {"tubes": "x"}, [[32, 24]], [32, 24.0], MAX_TUBES + 1]
ODD_FIELDS = ["", "nan", "inf", "-inf", "x", "-1", "1e400", "3.5", "0", "7", " ", '"1"', "1,2", "\x7f", "\u00e9"]
GARBAGE = st.binary(min_size=1, max_size=40)


@st.composite
def meta_mutation(draw, meta: dict):
    """``session.json`` bytes: ``meta`` with keys deleted, renamed or given odd values, or the text cut or garbled."""
    meta = json.loads(json.dumps(meta))
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(sorted(meta))) if meta else "cameras"
        kind = draw(st.sampled_from(["delete", "rename", "value", "tube"]))
        if kind == "delete":
            meta.pop(key, None)
        elif kind == "rename":
            meta[key + draw(st.sampled_from(["_", "s", "X"]))] = meta.pop(key, None)
        elif kind == "value":
            meta[key] = draw(st.sampled_from(ODD_VALUES))
        else:
            meta["robot"] = {"tubes": [{"outer_diameter_mm": draw(st.sampled_from(ODD_VALUES))}]}
    data = json.dumps([meta] if draw(st.integers(0, 19)) == 0 else meta).encode()
    return _garble(draw, data)


def _garble(draw, data: bytes) -> bytes:
    """``data`` unchanged, cut, with garbage bytes inserted or replaced by garbage (the draws decide)."""
    how = draw(st.sampled_from(["keep", "keep", "keep", "cut", "insert", "garbage"]))
    at = draw(st.integers(0, len(data)))
    if how == "cut":
        return data[:at]
    if how == "insert":
        return data[:at] + draw(GARBAGE) + data[at:]
    return draw(GARBAGE) if how == "garbage" else data


@st.composite
def csv_mutation(draw, text: str):
    """``frames.csv`` bytes: lines deleted, repeated or invented, fields given odd values or added/removed, cut, garbled."""
    lines = text.split("\r\n")[:-1]
    for _ in range(draw(st.integers(0, 3))):
        i = draw(st.integers(0, len(lines) - 1)) if lines else 0
        kind = draw(st.sampled_from(["delete", "repeat", "invent", "field", "add", "remove", "rename"]))
        if not lines:
            break
        fields = lines[i].split(",")
        j = draw(st.integers(0, len(fields) - 1))
        if kind == "delete":
            del lines[i]
        elif kind == "repeat":
            lines.insert(i, lines[i])
        elif kind == "invent":
            lines.insert(i, ",".join(draw(st.lists(st.sampled_from(ODD_FIELDS), max_size=10))))
        elif kind in ("field", "rename"):
            fields[j] = draw(st.sampled_from(ODD_FIELDS)) if kind == "field" else fields[j] + "_x"
            lines[i] = ",".join(fields)
        else:
            lines[i] = ",".join(fields + ["1"] if kind == "add" else fields[:j] + fields[j + 1 :])
    end = draw(st.sampled_from(["\r\n", "\n", ""]))
    return _garble(draw, ("\r\n".join(lines) + end).encode("utf-8"))


def _assert_valid(s: Session) -> None:
    """What every Session that opens must be: consistent names, unique indices, finite numbers of the right counts."""
    assert s.frames and s.cameras and set(s.cameras) == set(s.rig.names)
    assert isinstance(s.n_tubes, int) and 0 <= s.n_tubes <= MAX_TUBES
    assert len({f.index for f in s.frames}) == len(s.frames)
    for f in s.frames:
        assert isinstance(f.index, int) and f.index >= 0 and math.isfinite(f.t_s) and math.isfinite(f.skew_ms)
        for joints in (f.extension_mm, f.rotation_deg):
            assert joints is None or (len(joints) == s.n_tubes and all(math.isfinite(v) for v in joints))
    w, h = s.image_size if s.image_size != (0, 0) else (1, 1)
    assert isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0
    s.robot_tube_radii_mm  # noqa: B018 - checked at load: it must not raise now
    assert all("\n" not in n for n in s.notes)


@pytest.fixture(scope="module")
def fuzz_dir(template, tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzz") / "session"
    shutil.copytree(template, d)
    return d


def test_fuzzed_session_json_and_frames_csv_never_escape(fuzz_dir, template):
    meta = json.loads((template / "session.json").read_text())
    text = (template / "frames.csv").read_bytes().decode()
    columns = frame_columns(["side", "top"], 2)
    assert text.startswith(",".join(columns) + "\r\n")

    @settings(max_examples=2000 if LONG else 400)
    @given(meta_bytes=meta_mutation(meta), csv_bytes=csv_mutation(text))
    def run(meta_bytes, csv_bytes):
        (fuzz_dir / "session.json").write_bytes(meta_bytes)
        (fuzz_dir / "frames.csv").write_bytes(csv_bytes)
        try:
            s = Session(fuzz_dir)
        except SessionError as exc:
            msg = str(exc)
            assert "\n" not in msg and "\r" not in msg, msg
            assert msg.startswith(str(fuzz_dir)), msg
            return
        _assert_valid(s)

    run()


def test_column_order_does_not_change_the_records(session):
    """Rows in the writer's column order take a fast path; any other order the checking one: same records."""
    lines = [ln.split(",") for ln in _csv_lines(session)]
    order = [0, 2, 1, 4, 3, 8, 7, 6, 5]
    _write_csv(session, [",".join(fields[i] for i in order) for fields in lines])
    shuffled = Session(session).frames
    _write_csv(session, [",".join(fields) for fields in lines])
    assert shuffled == Session(session).frames and len(shuffled) == N_FRAMES


# ----------------------------------------------------------------------------- memory bound

def _claim_size(d: Path, camera: str, width: int, height: int) -> None:
    """Make rig.json claim ``width`` x ``height`` px for ``camera`` (principal point at the centre); no image is touched."""
    rig = json.loads((d / "rig.json").read_text())
    cam = rig["cameras"][camera]
    cam["width"], cam["height"] = width, height
    cam["K"][0][2], cam["K"][1][2] = (width - 1) / 2, (height - 1) / 2
    (d / "rig.json").write_text(json.dumps(rig))


def test_a_session_beyond_the_memory_bound_is_refused_with_the_figure(session, monkeypatch):
    """Issue 15 item 6: an 8000x6000 session took 8-9.6 GB; it is refused at load, before any image is read."""
    monkeypatch.delenv("CTR_BENCH_MEMORY_LIMIT_GB", raising=False)
    _claim_size(session, "top", 8000, 6000)
    msg = _error(session)
    # 260 MB + (120 + 14 x 6 background frames) bytes x 48e6 px = 10.05 GB
    assert msg == (f"{session / 'rig.json'}: cameras.top: reconstructing 8000x6000 px frames with 6 background frames "
                   "needs about 10.1 GB (limit 4.0 GB; CTR_BENCH_MEMORY_LIMIT_GB raises it)")
    monkeypatch.setenv("CTR_BENCH_MEMORY_LIMIT_GB", "16")
    assert Session(session).rig["top"].width == 8000  # a bigger machine may allow it
    monkeypatch.setenv("CTR_BENCH_MEMORY_LIMIT_GB", "0.1")
    _claim_size(session, "top", W, H)
    assert "needs about 0.3 GB (limit 0.1 GB;" in _error(session)  # the template itself, under a lowered limit
    monkeypatch.setenv("CTR_BENCH_MEMORY_LIMIT_GB", "lots")
    assert _error(session) == f"{session}: CTR_BENCH_MEMORY_LIMIT_GB='lots': must be a positive number of GB"
