"""Only the renderer needs OpenGL: every command and the twin's other modules import without it.

`fit`, `verify`, `experiment` and `report` must work on a machine without EGL/OSMesa, so
importing them (the CLI imports every command to list them) must neither import OpenGL nor
choose a platform. A fresh interpreter checks it, since PyOpenGL stays bound once imported.
"""
import json
import os
import subprocess
import sys

CODE = """
import importlib, json, os, sys
import rig.cli, twin, twin.kinematics, twin.scene, twin.modelfit, twin.record, twin.simulator, twin.robot
for name in rig.cli.COMMANDS:
    importlib.import_module("rig.cli.commands." + name)
print(json.dumps({"opengl": sorted(m for m in sys.modules if m.split(".")[0] in ("OpenGL", "pyrender")),
                  "platform": os.environ.get("PYOPENGL_PLATFORM")}))
"""


def test_commands_and_twin_import_no_opengl():
    env = {k: v for k, v in os.environ.items() if k not in ("PYOPENGL_PLATFORM", "CTR_BENCH_GL")}
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, check=True)
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen == {"opengl": [], "platform": None}, seen
