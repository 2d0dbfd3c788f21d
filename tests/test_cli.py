"""The ``ctr-bench`` entry point: options checked before any work, and the version."""
from __future__ import annotations

import pytest

from rig.cli import main


@pytest.mark.parametrize("command", [["run", "scenes/paper.toml", "--method"],
                                     ["reconstruct", "no-such-session", "--out", "unused", "--method"],
                                     ["tune", "scenes/tune", "--out", "unused.toml", "--method"],
                                     ["bench", "--methods"], ["bench", "--suite", "wide", "--n", "1", "--methods"],
                                     ["experiment", "scenes/paper-sequence.toml", "--rig", "scenes/rig-twin.toml", "--out", "unused",
                                      "--dry-run", "--reconstruct"]])
def test_an_unknown_method_is_refused_before_any_work(command, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path.parent)  # nothing may be written where the command runs
    before = set(tmp_path.parent.iterdir())
    with pytest.raises(SystemExit) as exc:
        main([*command, "nope"])
    assert exc.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert ("--method" in last or "--reconstruct" in last) and "unknown method 'nope'" in last and "paper" in last and "fast" in last, last
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


def _options() -> dict:
    """Option string -> [(command, argparse action)] over every sub-command (and sub-sub-command)."""
    import argparse

    from rig.cli import _parser

    out = {}

    def walk(name, parser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, p in action.choices.items():
                    walk(f"{name} {sub}".strip(), p)
            for opt in action.option_strings:
                out.setdefault(opt, []).append((name, action))

    walk("", _parser())
    return out


#: One meaning per option name (issue 14, item 7): a file, a frame LIST or a count, whichever command it is given to.
SAME_MEANING = {"--params": "FILE", "--frames": "LIST", "--background-frames": "LIST", "--n-frames": "N",
                "--n-background-frames": "N"}


@pytest.mark.parametrize("option, metavar", sorted(SAME_MEANING.items()))
def test_an_option_name_means_one_thing_in_every_command(option, metavar):
    uses = _options().get(option, [])
    assert uses, f"no command takes {option}"
    assert {(cmd, a.metavar) for cmd, a in uses} == {(cmd, metavar) for cmd, _ in uses}


def test_counts_and_frame_lists_are_parsed_by_one_parser_each(capsys):
    from rig.cli.options import parse_frames

    counts = [a for opt in ("--n-frames", "--n-background-frames") for _, a in _options()[opt]]
    assert {a.type.__qualname__ for a in counts} == {"count.<locals>.parse"}
    assert parse_frames("3,7,10-12") == {3, 7, 10, 11, 12} and parse_frames(None) is None
    with pytest.raises(ValueError, match="--background-frames '1-x': expected frame numbers"):
        parse_frames("1-x", "--background-frames")
    with pytest.raises(SystemExit):
        main(["render", "--frames", "2", "--out", "unused"])  # the old count syntax is refused, not reread as a LIST
    assert "unrecognized arguments: --frames" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "--n-frames", "0"])
    assert "argument --n-frames: must be >= 1, got 0" in capsys.readouterr().err


def test_every_method_option_checks_its_names_when_read():
    from rig.cli.commands.bench import method_list
    from rig.cli.options import method_name

    uses = _options()
    assert {a.type for _, a in uses["--method"]} == {method_name}
    assert {a.type for _, a in uses["--methods"]} == {method_list}
