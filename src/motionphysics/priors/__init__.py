"""Diffusion motion priors behind one interface (:class:`~.base.VideoPrior`).

``PRIORS`` is the registry the CLI (``--prior``) and the config (``optimize.prior``)
validate against; ``none`` means no prior. Entries are lazy ``module:Class`` strings, so
diffusers is imported only when a diffusers prior is asked for.
"""

from __future__ import annotations

from motionphysics.priors.base import GuidedPrediction, TextEmbeddings, VideoPrior
from motionphysics.registry import Registry

__all__ = ["PRIORS", "GuidedPrediction", "TextEmbeddings", "VideoPrior", "load_prior"]

PRIORS: Registry[type[VideoPrior]] = Registry(
    "video prior",
    "optimize.prior",
    {
        "motion": "motionphysics.priors.motion:MotionPrior",
        "tiny": "motionphysics.priors.tiny:TinyPrior",
        "cogvideox": "motionphysics.priors.cogvideox:CogVideoXPrior",
        "modelscope": "motionphysics.priors.modelscope:ModelScopePrior",
    },
)


def load_prior(name: str, path: str | None = None, *, device: str = "cpu", **options) -> VideoPrior:
    """Load the prior registered as ``name`` from ``path`` (None: its embedded default)."""
    return PRIORS.get(name).from_pretrained(path, device=device, **options)
