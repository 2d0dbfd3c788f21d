"""rig: hardware abstraction (cameras, actuators), recording and replay, experiments and the CLI."""
