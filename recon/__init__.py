"""recon: reconstruction of a concentric tube robot's backbone from two calibrated views.

Pure functions over numpy arrays with frozen parameter dataclasses. This package
imports neither ``twin`` nor ``rig``: it runs unchanged on real frames.
"""

from ._lazy import lazy_exports

#: Public name -> module that owns it (loaded on first use: importing the package alone does not pull in numba and the methods).
_EXPORTS = {
    "Camera": "recon.camera",
    "invert_transform": "recon.geometry", "compose": "recon.geometry", "transform_points": "recon.geometry",
    "look_at": "recon.geometry", "arc_length": "recon.geometry", "resample_polyline": "recon.geometry",
    "closest_arc_length": "recon.geometry",
    "RigCalibration": "recon.rigcal", "load_rig_calibration": "recon.rigcal", "save_rig_calibration": "recon.rigcal",
    "FrameError": "recon.errors",
    "METHODS": "recon.methods", "get_method": "recon.methods", "prepare": "recon.methods", "register_method": "recon.methods",
    "PaperParams": "recon.paper", "FastParams": "recon.fast",
    "backbone_errors": "recon.metrics", "point_to_polyline_distances": "recon.metrics",
    "SelfCheckParams": "recon.selfcheck", "prepare_selfcheck": "recon.selfcheck", "check_backbone": "recon.selfcheck",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
