"""Public names of a package loaded on first use (PEP 562), so that importing the package stays cheap."""
from __future__ import annotations

from importlib import import_module


def lazy_exports(package: str, exports: dict, namespace: dict) -> tuple:
    """``(__getattr__, __dir__)`` for ``package`` whose public name -> owning module map is ``exports``.

    Parameters
    ----------
    package : str
        The package's dotted name, used in the ``AttributeError`` message.
    exports : dict of str to str
        Public name -> dotted name of the module defining it (imported on first access).
    namespace : dict
        The package's ``globals()``; its names are listed by ``__dir__`` with the lazy ones.

    Returns
    -------
    tuple of (callable, callable)
        The module-level ``__getattr__(name)`` (raises ``AttributeError`` for a name not in
        ``exports``) and ``__dir__()`` (sorted names) to assign in the package.
    """

    def __getattr__(name: str):
        if name in exports:
            return getattr(import_module(exports[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
