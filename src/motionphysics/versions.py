"""Versions of the packages that shape a run's numbers (recorded in ``run.yaml`` and
``params.json``). A leaf module: imports nothing of the project but its version."""

from __future__ import annotations

import platform
from importlib import metadata

from motionphysics import __version__

__all__ = ["versions"]


def versions() -> dict[str, str]:
    """``{motionphysics, python, torch, warp, numpy}`` versions (those installed)."""
    out = {"motionphysics": __version__, "python": platform.python_version()}
    for dist, key in (("torch", "torch"), ("warp-lang", "warp"), ("numpy", "numpy")):
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out
