"""Issue 15, items 3-6: the rig calibration, the parameter files and the scene TOML are validated at load.

Every reproduction of the issue (a sheared or scaled rotation, k1 = 50, fx = 0, NaN in K, a
camera missing or renamed, ``cameras`` as a list, ``knot_mm = inf``, ``max_ray_gap_mm = nan``,
``outer_diameter_mm = inf``, ``[carving] resolution = 2000``, an 8192x8192 scene) is refused
in one line naming the file and the key; the files ctr-bench writes and ships stay valid; and
hypothesis mutates valid files (deletions, type swaps, NaN/inf, truncation, binary garbage,
renamed keys) to show that every outcome is such a line or a valid object.
"""
from __future__ import annotations

import copy
import json
import math
import sys

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from recon.calibration_check import CalibrationError, camera_problems, check_rig, distortion_problem, rotation_problem
from recon.camera import Camera
from recon.fast import FastParams
from recon.memory import LIMIT_ENV, MemoryBoundError, carving_bytes, memory_limit_bytes, render_bytes
from recon.methods import get_method
from recon.paper import PaperParams
from recon.params import load_params, params_from_dict, params_to_dict
from recon.rigcal import RigCalibration, load_rig_calibration, save_rig_calibration
from twin.scene import SceneError, check_scene_cameras, load_scene, read_toml, scene_from_dict
from twin.scenegen import generate_suite

from conftest import SCENES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PAPER_TOML = (SCENES / "paper.toml").read_text()
TUNED = SCENES.parent / "params" / "paper-tuned.toml"


def one_line_naming(exc: BaseException, path, *parts: str) -> str:
    """The message of ``exc`` after checking it is one line that starts with ``path`` and holds ``parts``."""
    msg = str(exc)
    assert "\n" not in msg, msg
    assert msg.startswith(str(path)), msg
    for part in parts:
        assert part in msg, msg
    return msg


@pytest.fixture(scope="module")
def rig_doc(paper_scene) -> dict:
    """The paper rig as rig.json holds it (what ``ctr-bench render`` writes)."""
    return json.loads(json.dumps(paper_scene.rig.to_dict()))


def _write_json(tmp_path, doc, name="rig.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc, indent=1))
    return path


# ----------------------------------------------------------------------------- rig.json reproductions
def _side(doc: dict) -> dict:
    return doc["cameras"]["side"]


def _shear(doc):
    _side(doc)["T_cam_world"][0][1] += 0.2


def _scale(doc):
    T = np.asarray(_side(doc)["T_cam_world"])
    T[:3, :3] *= 1.2
    _side(doc)["T_cam_world"] = T.tolist()


def _reflect(doc):
    _side(doc)["T_cam_world"][2] = [-v for v in _side(doc)["T_cam_world"][2][:3]] + [_side(doc)["T_cam_world"][2][3]]


def _set_k1(value):
    def mutate(doc):
        _side(doc)["dist"][0] = value
    return mutate


def _set_K(i, j, value):
    def mutate(doc):
        _side(doc)["K"][i][j] = value
    return mutate


def _cameras_as_list(doc):
    doc["cameras"] = [dict(c, name=n) for n, c in doc["cameras"].items()]


def _drop_top(doc):
    del doc["cameras"]["top"]


def _rename_top(doc):
    doc["cameras"]["front"] = dict(doc["cameras"].pop("top"), name="front")


def _rename_top_key(doc):
    doc["cameras"]["front"] = doc["cameras"].pop("top")


def _inner_name(doc):
    _side(doc)["name"] = "top"


def _misspelt_key(doc):
    _side(doc)["distortion"] = _side(doc).pop("dist")


RIG_CASES = {
    "sheared rotation": (_shear, "cameras.side.T_cam_world", "not orthonormal"),
    "rotation scaled by 1.2": (_scale, "cameras.side.T_cam_world", "not orthonormal"),
    "reflection": (_reflect, "cameras.side.T_cam_world", "det"),
    "k1 = 50": (_set_k1(50.0), "cameras.side.dist", "distorts the image corners by +88 %"),
    "k1 = -5 (folds)": (_set_k1(-5.0), "cameras.side.dist", "folds the image over"),
    "fx = 0": (_set_K(0, 0, 0.0), "cameras.side.K", "focal lengths must be > 0"),
    "NaN in K": (_set_K(0, 2, math.nan), "cameras.side.K", "finite"),
    "inf in K": (_set_K(1, 1, math.inf), "cameras.side.K", "finite"),
    "principal point outside": (_set_K(0, 2, 5000.0), "cameras.side.K", "principal point"),
    "cameras as a list": (_cameras_as_list, "cameras", "must be an object mapping camera names"),
    "camera missing": (_drop_top, "cameras", "no camera 'top'"),
    "camera renamed": (_rename_top, "cameras", "no camera 'top'"),
    "camera key renamed": (_rename_top_key, "cameras.front.name", "'top' differs from the camera's key 'front'"),
    "name inside differs": (_inner_name, "cameras.side.name", "must agree"),
    "misspelt key": (_misspelt_key, "cameras.side.distortion", "unknown key"),
}


@pytest.mark.parametrize("case", list(RIG_CASES))
def test_bad_rig_calibration_is_one_line_naming_file_and_key(tmp_path, rig_doc, case):
    mutate, key, why = RIG_CASES[case]
    doc = copy.deepcopy(rig_doc)
    mutate(doc)
    path = _write_json(tmp_path, doc)
    with pytest.raises(CalibrationError) as err:
        load_rig_calibration(path, cameras=("side", "top"))
    one_line_naming(err.value, path, f": {key}", why)


def test_a_camera_the_rig_lacks_is_a_value_error_naming_the_file(tmp_path, rig_doc):
    doc = copy.deepcopy(rig_doc)
    _rename_top(doc)
    path = _write_json(tmp_path, doc)
    rig = load_rig_calibration(path)  # no names asked for: the file itself is sound
    for kind in (ValueError, KeyError):  # the CLI prints ValueErrors; lookups catch KeyErrors
        with pytest.raises(kind) as err:
            rig["top"]
        one_line_naming(err.value, path, "no camera 'top'", "has side, front")


@pytest.mark.parametrize("text, why", [("", "not valid JSON"), ("[1, 2]", "must be a JSON object"),
                                       ('{"cameras": {}}', "no cameras"), ("\x00\xff garbage", "not UTF-8 text")])
def test_rig_file_that_is_no_rig_is_one_line(tmp_path, text, why):
    path = tmp_path / "rig.json"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(CalibrationError) as err:
        load_rig_calibration(path)
    one_line_naming(err.value, path, why)


def test_rig_files_ctr_bench_writes_stay_valid(tmp_path, paper_scene):
    path = tmp_path / "rig.json"
    save_rig_calibration(path, paper_scene.rig)
    rig = load_rig_calibration(path, cameras=("side", "top"))
    for name in ("side", "top"):
        np.testing.assert_array_equal(rig[name].K, paper_scene.rig[name].K)
        np.testing.assert_array_equal(rig[name].T_cam_world, paper_scene.rig[name].T_cam_world)


def test_rig_checks_state_their_tolerances():
    T = np.eye(4)
    T[0, 1] = 0.9e-6  # within ROTATION_TOL
    assert rotation_problem(T) is None
    T[0, 1] = 2e-6
    assert "2e-06 > 1e-06" in rotation_problem(T)
    # a rotation typed with 4 decimals is refused with the figure, not silently used
    c = math.sqrt(0.5)
    R = np.round([[c, -c, 0], [c, c, 0], [0, 0, 1]], 4)
    T = np.eye(4)
    T[:3, :3] = R
    assert "not orthonormal" in rotation_problem(T)


def test_distortion_check_refuses_only_lenses_that_fold_or_are_no_lens():
    K = np.array([[1200.0, 0.0, 639.5], [0.0, 1200.0, 479.5], [0.0, 0.0, 1.0]])

    def cam(dist):
        return Camera("c", 1280, 960, K, dist)

    # the wide suite's extremes, both ways
    assert distortion_problem(cam([-0.25, 0.12, 0.002, -0.002, 0.04])) is None
    assert distortion_problem(cam([0.25, -0.12, -0.002, 0.002, -0.04])) is None
    assert "folds the image over" in distortion_problem(cam([-2.0, 0.0, 0.0, 0.0, 0.0]))
    # a rational model whose denominator outgrows the numerator folds too: r / (1 + 3 r^2) peaks at 0.29 < 0.67
    assert "folds the image over" in distortion_problem(cam([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0]))
    # ... but one that magnifies towards a pole beyond the corners does not fold the image
    assert distortion_problem(cam([0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0])) is None
    # the net effect at the corners counts: k1 = 12 that k2 halves there is a lens; k1 = 50 is not
    narrow = Camera("c", 1024, 768, [[2580.0, 0.0, 511.5], [0.0, 2580.0, 383.5], [0.0, 0.0, 1.0]], [12.0, -150.0, 0, 0, 0])
    assert distortion_problem(narrow) is None
    assert "beyond any lens" in distortion_problem(Camera("c", 1024, 768, narrow.K, [50.0, 0.04, 0.0, 0.0, 0.0]))


def test_generated_wide_scenes_and_shipped_scenes_pass_the_camera_checks():
    """The wide suite draws principal-point offsets and |k1| <= 0.25 with k2, k3, p1, p2: all accepted."""
    for s in generate_suite("wide", 24, 1):
        scene = scene_from_dict(s.data, source=s.name)
        check_scene_cameras(scene)
        check_rig(scene.rig, s.name, cameras=("side", "top"))
    for path in sorted(SCENES.glob("*.toml")) + sorted(SCENES.glob("*/*.toml")):
        data = read_toml(path, "scene")
        if data.get("format", "ctr-bench-scene") == "ctr-bench-scene" and "sequence" in data:
            load_scene(path)


# ----------------------------------------------------------------------------- parameter files
def _params_file(tmp_path, text: str, name="params.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


PARAM_CASES = {
    "knot_mm = inf": ("fast", "knot_mm = inf\n", "knot_mm", "must be a finite number"),
    "max_ray_gap_mm = nan": ("fast", "max_ray_gap_mm = nan\n", "max_ray_gap_mm", "must be a finite number"),
    "max_ray_gap_mm = 0": ("fast", "max_ray_gap_mm = 0.0\n", "max_ray_gap_mm", "must be > 0"),
    "negative margin": ("paper", "[carving]\nmargin_mm = -1.0\n", "carving.margin_mm", "must be >= 0"),
    "resolution = 2000": ("paper", "[carving]\nresolution = 2000\n", "carving.resolution", "needs about 15.5 GB (limit 4.0 GB"),
    "coarse_resolution = 10**6": ("paper", "[carving]\ncoarse_resolution = 1000000\n", "carving.coarse_resolution", "GB (limit"),
    "huge integer": ("paper", "[carving]\nresolution = 99999999999999999999999\n", "carving.resolution", "64-bit integer"),
    "subvoxel table": ("paper", "[subvoxel]\niterations = -2\n", "subvoxel.iterations", "must be >= 0"),
}


@pytest.mark.parametrize("case", list(PARAM_CASES))
def test_bad_parameter_file_is_one_line_naming_file_and_key(tmp_path, case):
    method, text, key, why = PARAM_CASES[case]
    path = _params_file(tmp_path, text)
    with pytest.raises(ValueError) as err:
        load_params(get_method(method).params_type, path, method)
    one_line_naming(err.value, path, f": {key}: ", why)


def test_memory_limit_follows_the_environment(tmp_path, monkeypatch):
    path = _params_file(tmp_path, "[carving]\nresolution = 2000\n")
    monkeypatch.setenv(LIMIT_ENV, "20")
    assert memory_limit_bytes() == 20e9
    assert load_params(PaperParams, path).carving.resolution == 2000  # 15.5 GB < 20 GB
    monkeypatch.setenv(LIMIT_ENV, "lots")
    with pytest.raises(MemoryBoundError, match=LIMIT_ENV):
        memory_limit_bytes()


def test_memory_estimates_grow_as_their_allocations():
    assert carving_bytes(200) == pytest.approx(8 * carving_bytes(100), rel=1e-3)
    assert carving_bytes(100) < 5e6  # the default grid: a few MB
    assert render_bytes(8192, 8192) > 10e9 > render_bytes(2448, 2048)  # the wide suite's largest sensor fits


def test_parameter_files_ctr_bench_writes_stay_valid():
    assert load_params(PaperParams, TUNED, "paper").carving.resolution == 135
    for cls in (PaperParams, FastParams):
        assert params_to_dict(params_from_dict(cls, params_to_dict(cls()), "defaults")) == params_to_dict(cls())


@pytest.mark.parametrize("content, why", [(b"\x00\xff\xfe garbage", "not UTF-8 text"), (b"knot_mm = ", "not valid TOML"),
                                          (b'method = 3\n', "method: must be a method name")])
def test_parameter_file_that_is_no_toml_is_one_line(tmp_path, content, why):
    path = tmp_path / "params.toml"
    path.write_bytes(content)
    with pytest.raises(ValueError) as err:
        load_params(FastParams, path, "fast")
    one_line_naming(err.value, path, why)


# ----------------------------------------------------------------------------- scene files
SCENE_CASES = {
    "outer_diameter_mm = inf": ("outer_diameter_mm = 1.6", "outer_diameter_mm = inf", "robot.tubes[0].outer_diameter_mm",
                                "must be finite"),
    "length_mm = nan": ("length_mm = 200.0", "length_mm = nan", "robot.tubes[0].length_mm", "must be"),
    "8192x8192": ("width = 1024\nheight = 768", "width = 8192\nheight = 8192", "image",
                  "rendering two 8192x8192 px views needs about 13.7 GB (limit 4.0 GB"),
    "principal point outside": ("principal_offset_px = [4.0, -3.0]", "principal_offset_px = [900.0, -3.0]",
                                "rig.side.principal_offset_px", "outside the 1024x768 image"),
    "folding lens": ("principal_offset_px = [4.0, -3.0]", "principal_offset_px = [4.0, -3.0]\ndistortion = [-5.0, 0, 0, 0, 0]",
                     "rig.side.distortion", "folds the image over"),
}


@pytest.mark.parametrize("case", list(SCENE_CASES))
def test_bad_scene_is_one_line_naming_file_and_key(tmp_path, case):
    old, new, key, why = SCENE_CASES[case]
    assert old in PAPER_TOML
    path = tmp_path / "bad.toml"
    path.write_text(PAPER_TOML.replace(old, new, 1))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    one_line_naming(err.value, path, f": {key}: ", why)


# ----------------------------------------------------------------------------- through the command line
@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A one-frame render of the paper scene (its rig.json is replaced by the tests)."""
    from rig.cli import main

    out = tmp_path_factory.mktemp("val") / "session"
    assert main(["render", str(SCENES / "paper.toml"), "--n-frames", "1", "--n-background-frames", "6", "--quiet",
                 "--out", str(out)]) == 0
    return out


def _cli_error(capsys, argv) -> str:
    from rig.cli import main

    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert err.count("\n") == 0, err
    return err


@pytest.mark.parametrize("case", ["sheared rotation", "k1 = 50", "fx = 0", "NaN in K", "cameras as a list",
                                  "camera missing", "camera renamed"])
def test_reconstruct_refuses_a_bad_rig_json_in_one_line(tmp_path, session, capsys, case):
    import shutil

    sess = tmp_path / "session"
    shutil.copytree(session, sess)
    doc = json.loads((sess / "rig.json").read_text())
    mutate, key, _ = RIG_CASES[case]
    mutate(doc)
    (sess / "rig.json").write_text(json.dumps(doc))
    err = _cli_error(capsys, ["reconstruct", str(sess), "--method", "fast", "--out", str(tmp_path / "out"), "--no-report"])
    assert "rig.json" in err and "Traceback" not in err, err


@pytest.mark.parametrize("case", ["knot_mm = inf", "max_ray_gap_mm = nan", "resolution = 2000"])
def test_reconstruct_refuses_a_bad_parameter_file_in_one_line(tmp_path, session, capsys, case):
    method, text, key, why = PARAM_CASES[case]
    path = _params_file(tmp_path, text)
    err = _cli_error(capsys, ["reconstruct", str(session), "--method", method, "--params", str(path),
                              "--out", str(tmp_path / "out"), "--no-report"])
    assert str(path) in err and key in err and why in err, err


@pytest.mark.parametrize("case", ["outer_diameter_mm = inf", "8192x8192"])
def test_render_refuses_a_bad_scene_before_rendering(tmp_path, capsys, case):
    old, new, key, why = SCENE_CASES[case]
    path = tmp_path / "bad.toml"
    path.write_text(PAPER_TOML.replace(old, new, 1))
    err = _cli_error(capsys, ["render", str(path), "--out", str(tmp_path / "out")])
    assert str(path) in err and key in err and why in err, err
    assert not (tmp_path / "out" / "session.json").exists()


# ----------------------------------------------------------------------------- fuzz
#: Values a mutation puts in place of one: NaN/inf, out of range, other types, huge.
NASTY = st.sampled_from([math.nan, math.inf, -math.inf, -1, 0, 0.0, -1e-9, 1e308, 2**70, True, "x", "", [], [1.5, "y"],
                         {}, {"a": 1}, [[0.0] * 4] * 4])


def _paths(doc, prefix=()):
    """Every (container path, key or index) of a nested dict/list document."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


def _parent(doc, path):
    for k in path[:-1]:
        doc = doc[k]
    return doc


@st.composite
def mutated(draw, base: dict):
    """``base`` with one structural mutation: a deletion, a type swap / NaN / inf, or a renamed key."""
    doc = copy.deepcopy(base)
    path = draw(st.sampled_from(sorted(_paths(doc), key=repr)))
    parent, key = _parent(doc, path), path[-1]
    op = draw(st.sampled_from(["delete", "replace", "rename"]))
    if op == "delete":
        del parent[key]
    elif op == "rename" and isinstance(parent, dict):
        parent[key + draw(st.sampled_from(["_x", "s", " "]))] = parent.pop(key)
    else:
        parent[key] = draw(NASTY)
    return doc


@st.composite
def corrupted(draw, text: str) -> bytes:
    """``text``'s bytes cut short or with a run of binary garbage written over them."""
    data = text.encode()
    at = draw(st.integers(0, len(data)))
    if draw(st.booleans()):
        return data[:at]
    junk = draw(st.binary(min_size=1, max_size=16))
    return data[:at] + junk + data[at + len(junk):]


def _outcome_is_clean(load, path, error=ValueError):
    """``load(path)`` returns an object or raises ``error`` in one line naming ``path``; anything else fails."""
    try:
        return load(path)
    except error as exc:
        one_line_naming(exc, path)
        return None


def _fuzz_settings(n):
    return settings(max_examples=n, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                           HealthCheck.too_slow])


@pytest.fixture(scope="module")
def rig_json_text(rig_doc) -> str:
    return json.dumps(rig_doc, indent=1)


@_fuzz_settings(120)
@given(data=st.data())
def test_fuzz_rig_json(tmp_path, rig_doc, rig_json_text, data):
    path = tmp_path / "rig.json"
    if data.draw(st.booleans()):
        path.write_text(json.dumps(data.draw(mutated(rig_doc))))
    else:
        path.write_bytes(data.draw(corrupted(rig_json_text)))
    rig = _outcome_is_clean(lambda p: load_rig_calibration(p, cameras=("side", "top")), path)
    if rig is not None:
        assert isinstance(rig, RigCalibration)
        check_rig(rig, str(path), ("side", "top"))
        for cam in rig.cameras.values():
            assert not camera_problems(cam)


PARAM_BASES = {"paper": tomllib.loads(TUNED.read_text()),
               "fast": dict(params_to_dict(FastParams(knot_mm=5.0, max_ray_gap_mm=1.5)), method="fast")}


@_fuzz_settings(120)
@given(data=st.data())
def test_fuzz_parameter_files(tmp_path, data):
    method = data.draw(st.sampled_from(sorted(PARAM_BASES)))
    base = PARAM_BASES[method]
    path = tmp_path / "params.toml"
    if data.draw(st.booleans()):
        path.write_text(tomli_w.dumps(data.draw(mutated(base))))
    else:
        path.write_bytes(data.draw(corrupted(tomli_w.dumps(base))))
    params = _outcome_is_clean(lambda p: load_params(get_method(method).params_type, p, method), path)
    if params is not None:
        assert isinstance(params, get_method(method).params_type)


@_fuzz_settings(80)
@given(data=st.data())
def test_fuzz_scene_files(tmp_path, data):
    path = tmp_path / "scene.toml"
    if data.draw(st.booleans()):
        path.write_text(tomli_w.dumps(data.draw(mutated(tomllib.loads(PAPER_TOML)))))
    else:
        path.write_bytes(data.draw(corrupted(PAPER_TOML)))
    scene = _outcome_is_clean(load_scene, path, SceneError)
    if scene is not None:
        assert scene.joints and scene.rig.names == ["side", "top"]


# The rig files and sequence files of `ctr-bench experiment` (docs/rig-file.md, docs/experiments.md).
RIG_TOML = (SCENES / "rig-twin.toml").read_text()
SEQUENCE_TOML = (SCENES / "paper-sequence.toml").read_text()


def _mutated_toml(data, text: str) -> bytes:
    if data.draw(st.booleans()):
        return tomli_w.dumps(data.draw(mutated(tomllib.loads(text)))).encode()
    return data.draw(corrupted(text))


@_fuzz_settings(80)
@given(data=st.data())
def test_fuzz_rig_files(tmp_path, data):
    from rig.hw.rigfile import RigFileError, load_rig_file

    (tmp_path / "paper.toml").write_text(PAPER_TOML)  # the scene the twin rig renders (relative to the file)
    path = tmp_path / "rig.toml"
    path.write_bytes(_mutated_toml(data, RIG_TOML))
    rig = _outcome_is_clean(load_rig_file, path, (RigFileError, SceneError))
    if rig is not None:
        assert rig.n_tubes >= 1


@_fuzz_settings(80)
@given(data=st.data())
def test_fuzz_sequence_files(tmp_path, data):
    from rig.hw.experiment import SequenceError, load_sequence

    path = tmp_path / "sequence.toml"
    path.write_bytes(_mutated_toml(data, SEQUENCE_TOML))
    seq = _outcome_is_clean(load_sequence, path, SequenceError)
    if seq is not None:
        assert seq.steps
