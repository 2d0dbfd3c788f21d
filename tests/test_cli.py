"""The ``ctr-bench`` entry point: options checked before any work, and the version."""
from __future__ import annotations

import pytest

from rig.cli import main


@pytest.mark.parametrize("command", [["run", "scenes/paper.toml"], ["reconstruct", "no-such-session", "--out", "unused"]])
def test_an_unknown_method_is_refused_before_any_work(command, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path.parent)  # nothing may be written where the command runs
    before = set(tmp_path.parent.iterdir())
    with pytest.raises(SystemExit) as exc:
        main([*command, "--method", "nope"])
    assert exc.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--method" in last and "unknown method 'nope'" in last and "paper" in last and "fast" in last, last
    assert set(tmp_path.parent.iterdir()) == before


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"ctr-bench {version('ctr-bench')}"


@pytest.mark.parametrize("value, says", [("2", "at least 3"), ("two", "an integer")])
def test_calibrate_min_views_errors_name_the_option(tmp_path, capsys, value, says):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", str(tmp_path), "--out", str(tmp_path / "rig.json"), "--min-views", value])
    assert exc.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--min-views" in last and says in last and "min_views" not in last, last
    assert not (tmp_path / "rig.json").exists()
