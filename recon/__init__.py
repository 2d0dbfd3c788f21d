"""recon: reconstruction of a concentric tube robot's backbone from two calibrated views.

Pure functions over numpy arrays with frozen parameter dataclasses. This package
imports neither ``twin`` nor ``rig``: it runs unchanged on real frames.
"""
