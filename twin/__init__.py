"""twin: the digital twin of the rig (robot kinematics, meshes, scene, rendering, ground truth)."""

from .gl import select_platform as _select_platform

# PyOpenGL binds its platform at first import: choose it before any submodule imports pyrender.
_select_platform()
