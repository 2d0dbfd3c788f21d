"""twin: the digital twin of the rig (robot kinematics, meshes, scene, rendering, ground truth)."""
