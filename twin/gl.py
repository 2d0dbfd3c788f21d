"""Choose the offscreen OpenGL platform before anything imports PyOpenGL.

PyOpenGL binds its platform once, at first import, from ``PYOPENGL_PLATFORM``.
Only :mod:`twin.render` calls :func:`select_platform` (when it is imported); this
module itself imports no OpenGL, so :func:`available_platforms` is safe anywhere.
We support OSMesa (CPU, ``libOSMesa``; Mesa dropped it in 25.1) and EGL (Mesa's
EGL renders without a GPU through llvmpipe, and uses a GPU where one exists).

Order: an explicit ``CTR_BENCH_GL`` or ``PYOPENGL_PLATFORM`` (``osmesa`` | ``egl``)
wins; otherwise EGL when its library is present (Mesa's EGL multisamples, so edges
are anti-aliased in one pass, and it is the platform Mesa keeps), else OSMesa.
"""
from __future__ import annotations

import ctypes.util
import os
import sys

__all__ = ["select_platform", "available_platforms"]

_PLATFORMS = ("osmesa", "egl")


def available_platforms() -> list:
    """Platforms whose shared library can be found on this machine."""
    found = []
    if ctypes.util.find_library("EGL"):
        found.append("egl")
    if ctypes.util.find_library("OSMesa"):
        found.append("osmesa")
    return found


def select_platform(preferred: str | None = None) -> str:
    """Set ``PYOPENGL_PLATFORM`` (once per process) and return it.

    Parameters
    ----------
    preferred : {"osmesa", "egl"}, optional
        Asked-for platform; overrides the environment.

    Raises
    ------
    RuntimeError
        If OpenGL was already imported with another platform, or none is available.
    """
    wanted = preferred or os.environ.get("CTR_BENCH_GL") or os.environ.get("PYOPENGL_PLATFORM")
    if wanted is not None and wanted not in _PLATFORMS:
        raise RuntimeError(f"CTR_BENCH_GL/PYOPENGL_PLATFORM: unknown OpenGL platform {wanted!r} (use osmesa or egl)")
    if "OpenGL" in sys.modules:
        current = os.environ.get("PYOPENGL_PLATFORM")
        if current is None:
            raise RuntimeError(
                "OpenGL was imported before the twin chose an offscreen platform: import twin.render first, "
                "or set PYOPENGL_PLATFORM=osmesa (or egl)"
            )
        if wanted and wanted != current:
            raise RuntimeError(f"OpenGL already initialised with {current!r}; start a new process to use {wanted!r}")
        return current
    if wanted is None:
        avail = available_platforms()
        if not avail:
            raise RuntimeError(
                "no offscreen OpenGL found: install Debian's libosmesa6 or libegl1 + libegl-mesa0 (scripts/setup.sh does)"
            )
        wanted = avail[0]
    os.environ["PYOPENGL_PLATFORM"] = wanted
    # pyrender imports its (unused) pyglet viewer, which needs X11 libraries unless pyglet
    # runs headless on EGL; a bare server has EGL but not libXrender.
    if "egl" in available_platforms():
        os.environ.setdefault("PYGLET_HEADLESS", "true")
    return wanted
