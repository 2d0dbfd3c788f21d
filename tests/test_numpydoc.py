"""Every public function of recon/ documents its parameters and return value (issue 16, item 7).

numpydoc style: a ``Parameters`` section wherever the function takes arguments
(``self`` and ``cls`` aside) and a ``Returns`` (or ``Yields``) section wherever it
returns a value. Public means not starting with ``_``, in a public class or at
module level; ``__call__`` counts as public. Properties count as methods: a short
``Returns`` section says the type and unit.
"""
from __future__ import annotations

import ast
from pathlib import Path

RECON = Path(__file__).resolve().parents[1] / "recon"


def _missing(path: Path) -> list:
    """``"<Class.>name P R"`` for each public function of ``path`` lacking Parameters (P) or Returns (R)."""
    out = []

    def visit(nodes, prefix=""):
        for n in nodes:
            if isinstance(n, ast.ClassDef) and not n.name.startswith("_"):
                visit(n.body, prefix + n.name + ".")
            if isinstance(n, ast.FunctionDef) and (not n.name.startswith("_") or n.name == "__call__"):
                doc = ast.get_docstring(n) or ""
                args = [a.arg for a in n.args.args + n.args.kwonlyargs if a.arg not in ("self", "cls")]
                need_p = bool(args) and "Parameters" not in doc
                has_ret = any(isinstance(x, ast.Return) and x.value is not None for x in ast.walk(n))
                need_r = has_ret and "Returns" not in doc and "Yields" not in doc
                if need_p or need_r:
                    out.append(prefix + n.name + (" P" if need_p else "") + (" R" if need_r else ""))

    visit(ast.parse(path.read_text(encoding="utf-8")).body)
    return out


def test_public_functions_have_parameters_and_returns():
    missing = {p.name: m for p in sorted(RECON.glob("*.py")) if (m := _missing(p))}
    assert not missing, "numpydoc sections missing (P: Parameters, R: Returns):\n" + "\n".join(
        f"  recon/{name}: {', '.join(m)}" for name, m in missing.items()
    )
