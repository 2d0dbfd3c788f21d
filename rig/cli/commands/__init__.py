"""Sub-commands of ``ctr-bench`` (one module each; see rig/cli/__init__.py)."""
