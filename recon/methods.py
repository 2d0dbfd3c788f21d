"""Reconstruction methods by name, behind one interface.

A method is prepared once per session (background models, per-camera constants)
and then called on each frame pair::

    reconstruct = prepare("paper", rig, background_frames, params)
    result = reconstruct({"side": img_side, "top": img_top})

The callable may keep state between frames (temporal priors). It raises
:class:`recon.errors.FrameError` with a one-line reason for a frame it cannot
reconstruct, and returns an object with at least ``points_world_mm`` (base
first), ``tip_world_mm``, ``length_mm``, ``transition_s_mm``,
``silhouettes``, ``centerlines`` and ``timings_ms`` (see
:class:`recon.paper.Reconstruction`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from . import paper

__all__ = ["Method", "METHODS", "get_method", "prepare", "register_method"]


@dataclass(frozen=True)
class Method:
    """A registered reconstruction method.

    Attributes
    ----------
    name : str
    params_type : type
        Frozen dataclass of its parameters (defaults = documented values).
    prepare : callable(rig, background_frames, params) -> callable(frames) -> result
    description : str
    """

    name: str
    params_type: type
    prepare: Callable
    description: str


def _prepare_paper(rig, background_frames, params):
    model = paper.prepare_paper(rig, background_frames, params)
    return lambda frames: paper.reconstruct_paper(model, frames, params)


METHODS: dict = {
    "paper": Method(
        "paper",
        paper.PaperParams,
        _prepare_paper,
        "Morimoto & Sketch: eigenbackgrounds, threshold, two-disk erosion centerline, 100^3 voxel carving",
    ),
}


def register_method(method: Method) -> None:
    """Add a method to :data:`METHODS` (used by modules defining further methods).

    Parameters
    ----------
    method : Method
        Registered under ``method.name``, replacing any method of that name.
    """
    METHODS[method.name] = method


def get_method(name: str) -> Method:
    """The method called ``name``; ValueError lists the known ones.

    Parameters
    ----------
    name : str
        A key of :data:`METHODS`, e.g. ``"paper"`` or ``"fast"`` (optional modules are imported first).

    Returns
    -------
    Method

    Raises
    ------
    ValueError
        ``name`` is not registered; the message lists the known names.
    """
    _load_optional_methods()
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r} (known: {', '.join(sorted(METHODS))})") from None


def prepare(name: str, rig, background_frames: dict, params=None):
    """Prepare method ``name`` for a session; returns the per-frame callable.

    Parameters
    ----------
    name : str
        The method's name (:func:`get_method`).
    rig : RigCalibration
        The calibrated cameras, by name (world frame, mm).
    background_frames : dict of str to ndarray
        Camera name -> ``(N, H, W)`` (or ``(N, H, W, 3)`` color) frames of the empty scene, gray levels 0-255.
    params : dataclass, optional
        The method's parameters (its ``params_type``); ``None`` uses the documented defaults.

    Returns
    -------
    callable
        ``reconstruct(frames)``: camera name -> image, returning the reconstruction (see the module
        docstring) or raising :class:`recon.errors.FrameError` for a frame it cannot reconstruct.

    Raises
    ------
    ValueError
        Unknown ``name``, or what the method's own preparation raises for unusable backgrounds.
    """
    m = get_method(name)
    return m.prepare(rig, background_frames, params if params is not None else m.params_type())


def _load_optional_methods() -> None:
    # Methods defined in their own modules register themselves on import.
    import importlib

    for module in ("recon.fast",):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
