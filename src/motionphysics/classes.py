"""The seven material classes of the paper, by name (a leaf module: the config, the
material catalogue and the simulator all import it, and it imports nothing)."""

from __future__ import annotations

__all__ = ["MATERIAL_CLASSES"]

MATERIAL_CLASSES = (
    "elastic",
    "plasticine",
    "metal",
    "foam",
    "sand",
    "newtonian",
    "non_newtonian",
)
"""Class names in the simulator's class-id order (``class_id`` = index)."""
