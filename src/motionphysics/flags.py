"""Flags that have no effect in a combination: refused or named, never silently ignored.

The commands (``run``, ``simulate``) call :func:`check_run_flags` with the resolved
config and the flags the user actually typed, before any work. A flag that cannot do
anything is an error (status 2, one line) when the user evidently expected an effect
that will not happen (an optimisation loss without a prior to optimise against), and
one warning line when the run is still what they asked for (``--init llm`` while the
config fixes every material field: the LLM would not be asked).

This module must not change the config; it only judges the combination.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from motionphysics.errors import UserInputError

__all__ = ["check_run_flags", "PRIOR_LOSSES", "material_fully_given"]

PRIOR_LOSSES = ("lmd", "sds", "flow")
"""Losses that read a video prior: without ``--prior`` nothing is optimised."""


def material_fully_given(material) -> bool:
    """Whether a ``MaterialConfig`` gives the class, the density and every parameter."""
    if material.class_ is None:
        return False
    from motionphysics.materials.catalog import MATERIALS

    given = material.overrides()
    need = [ps.name for ps in MATERIALS[material.class_].params if ps.default is None] + ["density"]
    return all(n in given for n in need)


def check_run_flags(cfg, given: Mapping[str, Any], command: str = "run") -> list[str]:
    """Judge the flags the user typed (``given``: flag name without dashes -> value).

    Raises :class:`UserInputError` for a flag with no effect that changes what the user
    expects; returns warning lines (``"warning: --init llm: ..."``) for the others.
    Keys understood: ``loss``, ``iters``, ``prior``, ``init``, ``params``.
    """
    warnings: list[str] = []
    prior = given.get("prior") or cfg.optimize.prior
    if given.get("loss") is not None and given["loss"] in PRIOR_LOSSES and prior == "none":
        raise UserInputError(
            f"--loss {given['loss']}: has no effect without a video prior (optimize.prior is "
            "none, so nothing is optimised); add --prior motion|cogvideox|modelscope, or drop --loss"
        )
    if given.get("iters") is not None and prior == "none" and not cfg.optimize.losses:
        raise UserInputError(
            f"--iters {given['iters']}: has no effect without a video prior (optimize.prior is "
            "none, so nothing is optimised); add --prior motion|cogvideox|modelscope"
        )
    init = given.get("init")
    if init is not None and material_fully_given(cfg.material):
        warnings.append(
            f"warning: --init {init}: has no effect, the config's material block gives the class "
            "and every parameter, so no estimate is made"
        )
    if init is not None and given.get("params") is not None:
        raise UserInputError(
            f"--init {init}: has no effect with --params (the params file gives the material); "
            "drop one of them"
        )
    return warnings
