"""rig: hardware abstraction (cameras, actuators), recording and replay, experiments and the CLI."""

from recon._lazy import lazy_exports

#: Public name -> module that owns it (loaded on first use; docs/api.md).
_EXPORTS = {
    "Session": "rig.session", "SessionWriter": "rig.session", "SessionError": "rig.session",
    "reconstruct_session": "rig.bench.reconstruct", "load_background_frames": "rig.bench.reconstruct",
    "load_run": "rig.bench.report", "build_report": "rig.bench.report",
    "render_scene_to": "rig.bench.scenes", "export_mcap": "rig.bench.mcap_export",
    "read_backbone_csv": "rig.backbone_csv", "write_backbone_csv": "rig.backbone_csv",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
