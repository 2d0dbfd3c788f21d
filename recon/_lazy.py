"""Public names of a package loaded on first use (PEP 562), so that importing the package stays cheap."""
from __future__ import annotations

from importlib import import_module


def lazy_exports(package: str, exports: dict, namespace: dict) -> tuple:
    """``(__getattr__, __dir__)`` for ``package`` whose public name -> owning module map is ``exports``."""

    def __getattr__(name: str):
        if name in exports:
            return getattr(import_module(exports[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
