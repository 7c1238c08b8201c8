"""Comparison init backends of the paper's ablation: ``median`` and ``naive``.

``median``: every parameter at the median of its range, ignoring what the prompt
says about the values (the class still has to come from somewhere: the kb
matcher's class decision, or a class given by the caller). The paper's median is
the *arithmetic* midpoint ``(lo + hi) / 2`` of each range, also for log-scaled
parameters (its ablation quotes E = 2e11 Pa for the elastic range 1e7-4e11, i.e.
the arithmetic midpoint): that is the default, ``median='arithmetic'``. The
median of the log-uniform distribution on the range, the geometric mean
``sqrt(lo * hi)`` (E = 6.3e9 Pa for elastic), is available as
``median='geometric'``; linear-scaled parameters use ``(lo + hi) / 2`` either way.

``naive``: an LLM asked without ranges, as PhysFlow does; its values are then
validated with clamping recorded (see :func:`motionphysics.init.llm.ask_material`).
"""

from __future__ import annotations

import math
from typing import Literal

from motionphysics.materials.catalog import DENSITY, MaterialParams, ParamSpec, ranges

__all__ = ["median_value", "median_params"]

MedianKind = Literal["arithmetic", "geometric"]


def median_value(ps: ParamSpec, kind: MedianKind = "arithmetic") -> float:
    """The median of a parameter's range (see the module docstring for ``kind``)."""
    if kind == "geometric" and ps.scale == "log":
        return math.sqrt(ps.low * ps.high)
    if kind not in ("arithmetic", "geometric"):
        raise ValueError(f"median kind must be 'arithmetic' or 'geometric', got {kind!r}")
    return 0.5 * (ps.low + ps.high)


def median_params(
    cls: str, kind: MedianKind = "arithmetic", table: str | None = None
) -> MaterialParams:
    """Every parameter of ``cls`` (and the density) at the median of its range in range
    table ``table`` (``extended``, ``paper``; None: the active one). The paper's ablation
    values (E = 2e11 Pa for elastic) come from ``table="paper"``."""
    mc = ranges(cls, table)
    values = {ps.name: median_value(ps, kind) for ps in mc.params}
    return MaterialParams(cls, median_value(DENSITY, kind), values)
