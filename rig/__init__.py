"""rig: hardware abstraction (cameras, actuators), recording and replay, experiments and the CLI."""

from recon._lazy import lazy_exports

#: Public name -> module that owns it (loaded on first use; docs/api.md).
_EXPORTS = {
    "Session": "rig.session", "SessionWriter": "rig.session", "SessionError": "rig.session",
    "reconstruct_session": "rig.reconstruct", "load_background_frames": "rig.reconstruct",
    "load_run": "rig.report", "build_report": "rig.report",
    "render_scene_to": "rig.commands.render", "export_mcap": "rig.mcap_export",
    "read_backbone_csv": "rig.backbone_csv", "write_backbone_csv": "rig.backbone_csv",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
