"""Sub-commands of ``ctr-bench`` (one module each; see rig/cli.py)."""
