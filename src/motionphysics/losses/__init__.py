"""Optimisation losses as plug-ins behind one interface (:class:`~.base.Loss`).

``get_loss(name)`` returns the loss class registered under ``name``; construct it with
its own arguments (a reference, a prior, weights). Entries are ``module:Class`` strings
so a heavy loss (a video prior) is imported only when asked for. Later losses (lmd,
sds, flow) register by adding an entry to ``_REGISTRY`` or calling :func:`register_loss`.
"""

from __future__ import annotations

import importlib

from motionphysics.errors import UserInputError
from motionphysics.losses.base import Loss, LossContext, Prediction

__all__ = ["Loss", "LossContext", "Prediction", "available_losses", "get_loss", "register_loss"]

_REGISTRY: dict[str, str | type[Loss]] = {
    "video_match": "motionphysics.losses.video_match:VideoMatchLoss",
    "trajectory_match": "motionphysics.losses.trajectory_match:TrajectoryMatchLoss",
}


def register_loss(name: str, cls: type[Loss] | str) -> None:
    """Register a loss class (or a lazy ``module:Class`` string) under ``name``."""
    _REGISTRY[name] = cls


def available_losses() -> list[str]:
    """Names accepted by :func:`get_loss`."""
    return sorted(_REGISTRY)


def get_loss(name: str) -> type[Loss]:
    """The loss class registered as ``name``; unknown names are a user error."""
    try:
        entry = _REGISTRY[name]
    except KeyError:
        raise UserInputError(
            f"optimize.loss: unknown loss {name!r}; expected one of {', '.join(available_losses())}"
        ) from None
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr)
        _REGISTRY[name] = entry
    return entry
