"""Diffusion motion priors behind one interface (:class:`~.base.VideoPrior`).

``PRIORS`` is the registry the CLI (``--prior``) and the config (``optimize.prior``)
validate against; ``none`` means no prior. Entries are lazy ``module:Class`` strings, so
diffusers is imported only when a diffusers prior is asked for.

``tiny``, the embedded pixel prior (a video diffusion model over rendered 32x32 clips),
was removed on 2026-12-03: it told motions apart in 20 % of held-out caption pairs
against a bar of 90 % (BENCHMARKS.md keeps its measurements). The name stays known to the
registry only so that asking for it is refused with that reason (:func:`removed_prior`).
"""

from __future__ import annotations

from motionphysics.priors.base import GuidedPrediction, TextEmbeddings, VideoPrior
from motionphysics.registry import Registry

__all__ = [
    "PRIORS",
    "GuidedPrediction",
    "TextEmbeddings",
    "VideoPrior",
    "load_prior",
    "removed_prior",
]

PRIORS: Registry[type[VideoPrior]] = Registry(
    "video prior",
    "optimize.prior",
    {
        "motion": "motionphysics.priors.motion:MotionPrior",
        "cogvideox": "motionphysics.priors.cogvideox:CogVideoXPrior",
        "modelscope": "motionphysics.priors.modelscope:ModelScopePrior",
    },
    removed={
        "tiny": "the embedded pixel prior was removed (it could not tell motions apart: "
        "20 % held-out caption discrimination)",
    },
)


def removed_prior(name: str, where: str = "--prior") -> str | None:
    """The one-line refusal of ``name`` when it names a removed prior, else None.

    ``where``: how the user asked for it: a flag (``--prior``, as typed on the command
    line) or a config field (``optimize.prior``); the way out is written in the same terms.
    """
    why = PRIORS.removed.get(name)
    if why is None or name in PRIORS:
        return None
    if where.startswith("--"):
        return (
            f"{where} {name}: {why}; use {where} motion (the embedded default) or "
            f"{where} cogvideox/modelscope with a local model path (--prior-path DIR)"
        )
    return (
        f"{where}: {name!r}: {why}; use {where}: motion (the embedded default) or "
        f"cogvideox/modelscope with a local model path ({where}_path: DIR)"
    )


def load_prior(name: str, path: str | None = None, *, device: str = "cpu", **options) -> VideoPrior:
    """Load the prior registered as ``name`` from ``path`` (None: its embedded default)."""
    return PRIORS.get(name).from_pretrained(path, device=device, **options)
