"""recon: reconstruction of a concentric tube robot's backbone from two calibrated views.

Pure functions over numpy arrays with frozen parameter dataclasses. This package
imports neither ``twin`` nor ``rig``: it runs unchanged on real frames.
"""

from importlib import import_module as _import_module

#: Public name -> module that owns it.
_EXPORTS = {
    "Camera": "recon.camera", "invert_transform": "recon.camera",
    "RigCalibration": "recon.rigcal", "load_rig_calibration": "recon.rigcal", "save_rig_calibration": "recon.rigcal",
    "FrameError": "recon.errors",
    "METHODS": "recon.methods", "get_method": "recon.methods", "prepare": "recon.methods", "register_method": "recon.methods",
    "PaperParams": "recon.paper", "FastParams": "recon.fast",
    "backbone_errors": "recon.metrics", "point_to_polyline_distances": "recon.metrics",
    "SelfCheckParams": "recon.selfcheck", "prepare_selfcheck": "recon.selfcheck", "check_backbone": "recon.selfcheck",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    # Loaded on first use: importing recon (e.g. for recon.camera alone) does not pull in numba and the methods.
    if name in _EXPORTS:
        return getattr(_import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'recon' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
