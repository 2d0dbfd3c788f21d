"""The ci Hypothesis profile draws the same examples in every run (tests/conftest.py)."""
from __future__ import annotations

import importlib
import os
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.skipif(os.environ.get("HYPOTHESIS_PROFILE", "ci") != "ci", reason="the ci profile's property")


def _draws() -> list:
    seen = []

    @settings(max_examples=200, database=None)
    @given(st.integers(0, 10**9))
    def record(x):
        seen.append(x)

    record()
    return seen


def test_the_examples_do_not_depend_on_the_modules_imported(tmp_path, monkeypatch):
    """Importing a project module full of literals between two runs of one derandomized test changes nothing:
    Hypothesis draws literals it finds in the imported local modules, so the examples of a ci run depended on
    the test files a pytest-xdist worker had run before (test_fast_method_accurate_inside_the_envelope failed
    alone and passed in the suite)."""
    before = _draws()
    literals = ", ".join(str(123456789 + 7919 * k) for k in range(300))
    (tmp_path / "many_literals.py").write_text(f"VALUES = ({literals})\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    importlib.import_module("many_literals")
    try:
        assert _draws() == before
    finally:
        sys.modules.pop("many_literals", None)
