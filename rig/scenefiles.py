"""Where the scene files that ship with ctr-bench are, in a source tree and in an installed wheel.

The repository keeps them in one place, the top-level ``scenes/`` folder (scenes,
the calibration scene, rig and sequence files, ``tune/`` and ``holdout/``; the
files they name, e.g. ``rig_scene = "paper.toml"``, are relative to the naming
file, so the folder travels whole). ``pyproject.toml`` maps that folder to the
data package ``rig.scenes``, so a wheel installs it as ``rig/scenes/``. A
source checkout (or an editable install, which runs the checkout) has no
``rig/scenes/`` and finds ``scenes/`` beside ``rig/``.

Every default scene path is built here: never ``Path(__file__).parents[n] /
"scenes"``, which only exists in a checkout.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["scenes_dir", "scene_path"]

_RIG = Path(__file__).resolve().parent


def scenes_dir() -> Path:
    """The folder of the bundled scenes: ``rig/scenes`` of a wheel, else ``scenes/`` of the checkout.

    When neither exists (an install made without its package data) it is the
    wheel's path, so that the error of whatever opens a file there names it.
    """
    installed, checkout = _RIG / "scenes", _RIG.parent / "scenes"
    # the wheel's copy first: an installed package must not read a checkout that happens to lie beside it
    if installed.is_dir() or not checkout.is_dir():
        return installed
    return checkout


def scene_path(*parts: str) -> Path:
    """A bundled file, e.g. ``scene_path("paper.toml")`` or ``scene_path("tune", "dim-flicker.toml")``.

    The path is returned whether or not the file exists; the loader that opens it
    names a missing file.
    """
    return scenes_dir().joinpath(*parts)


#: The scene run, render and bench use without a SCENE: the bundled paper scene (a checkout's
#: scenes/paper.toml, a wheel's rig/scenes/paper.toml; rig/scenefiles.py).
DEFAULT_SCENE = scene_path("paper.toml")
