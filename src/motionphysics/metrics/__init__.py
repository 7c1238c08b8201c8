"""Metrics of a simulated run: physical diagnostics (``physical``) and learned scores.

Submodules are imported directly; importing this package does no work.
"""
