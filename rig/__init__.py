"""rig: everything around the pipeline, in three wings over shared ground.

* ``rig.hw``: camera and actuator backends, rig files, the firmware and its emulator,
  experiments on a rig, imports of a lab's recordings;
* ``rig.bench``: sessions reconstructed and scored, peers, comparison, tuning, reports,
  scene renders and their cache;
* ``rig.cli``: the ``ctr-bench`` commands (argparse only);
* shared ground: the session format (:mod:`rig.session`, :mod:`rig.session_checks`), the
  run directory (:mod:`rig.rundir`, :mod:`rig.backbone_csv`), progress, tables, scene files
  and the live viewer.

The wings do not import each other; ``cli`` imports both.
"""

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
