"""Optimisation losses as plug-ins behind one interface (:class:`~.base.Loss`).

``LOSSES`` is the registry (lazy ``module:Class`` entries, so a heavy loss is imported
only when asked for); the CLI choices and ``optimize.loss`` / ``optimize.losses``
validate against it. Adding a loss is one module plus one entry here.
"""

from __future__ import annotations

from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction
from motionphysics.registry import Registry

__all__ = [
    "LOSSES",
    "Loss",
    "LossBuildContext",
    "LossContext",
    "Prediction",
    "available_losses",
    "get_loss",
    "register_loss",
]

LOSSES: Registry[type[Loss]] = Registry(
    "loss",
    "optimize.loss",
    {
        "video_match": "motionphysics.losses.video_match:VideoMatchLoss",
        "trajectory_match": "motionphysics.losses.trajectory_match:TrajectoryMatchLoss",
        "lmd": "motionphysics.losses.lmd:LmdLoss",
        "sds": "motionphysics.losses.sds:SdsLoss",
        "flow": "motionphysics.losses.flow:FlowLoss",
        "video": "motionphysics.losses.video:VideoLoss",
    },
)


def register_loss(name: str, cls: type[Loss] | str) -> None:
    """Register a loss class (or a lazy ``module:Class`` string) under ``name``."""
    LOSSES.register(name, cls)


def available_losses() -> list[str]:
    """Names accepted by :func:`get_loss`."""
    return LOSSES.names()


def get_loss(name: str) -> type[Loss]:
    """The loss class registered as ``name``; unknown names are a user error."""
    return LOSSES.get(name)
