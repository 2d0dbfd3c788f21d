"""twin: the digital twin of the rig (robot kinematics, meshes, scene, rendering, ground truth).

Importing it, or any module but :mod:`twin.render`, needs no OpenGL: the renderer picks the
offscreen platform (:func:`twin.gl.select_platform`) when it is imported, which a
:class:`twin.simulator.Twin` does when it is made.
"""
