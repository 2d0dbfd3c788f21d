"""docs/api.md runs as written (issue 14, item 6), and the packages export what it uses."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _blocks() -> list:
    return re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), flags=re.S)


def test_api_doc_runs(capsys, monkeypatch):
    blocks = _blocks()
    assert len(blocks) >= 6
    monkeypatch.chdir(ROOT)
    ns = {}
    for k, code in enumerate(blocks):
        exec(compile(code, f"docs/api.md block {k + 1}", "exec"), ns)  # noqa: S102 - the doc's own code
    out = capsys.readouterr().out
    assert "refused: top: " in out  # the blank frame is refused with a one-line reason naming its camera
    assert ns["result"].points_world_mm.shape[1] == 3
    assert ns["errors"]["mean_error_mm"] < 0.5, ns["errors"]
    assert ns["check"].ok, ns["check"].reason
    assert ns["summary"]["failed_frames"] == 0 and (ns["work"] / "top.png").stat().st_size > 1000
    assert ns["counts"]["/ctr/backbone"] == 2


@pytest.mark.parametrize("package", ["recon", "rig"])
def test_public_names_resolve(package):
    mod = __import__(package)
    assert mod.__all__
    for name in mod.__all__:
        assert getattr(mod, name) is not None, name
    with pytest.raises(AttributeError):
        getattr(mod, "no_such_name")
