"""The unconstrained optimisation vector theta and its inverse.

Each optimised parameter ``x`` with handbook range ``[lo, hi]`` (from the catalogue)
gets one real coordinate ``theta = logit(u)``, where ``u`` in (0, 1) is the position
of ``x`` in its range: ``u = (log x - log lo) / (log hi - log lo)`` for log-scaled
parameters (E, tau_Y, eta, mu, kappa, density), ``u = (x - lo) / (hi - lo)`` for linear
ones (nu, theta_fric, n). ``from_theta`` is therefore bounded by the ranges for any
real theta (Adam can never leave the plausible range), and differentiable.

Values exactly on a bound map to ``u = EPS`` or ``1 - EPS`` (theta finite);
values outside the range are an error (validate/clamp them first).

This module must not know about the simulator; chain
``from_theta -> simmap.physical_to_sim`` for that.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import torch

from motionphysics.materials.catalog import MATERIALS, MaterialParams, normalise_class, spec

__all__ = ["Parameterisation", "EPS"]

EPS = 1e-6
"""Distance from the bounds, in range fraction, at which ``to_theta`` places boundary values."""


class Parameterisation:
    """theta <-> physical values for a subset ``names`` of a class's parameters.

    ``ranges``: ``{name: (low, high)}`` replacing a name's handbook range (a start a
    person wrote outside it: :func:`motionphysics.optimize.fit.start_ranges`).

    ``names`` defaults to all of the class's parameters (density excluded);
    ``density`` may be listed explicitly. ``theta`` has shape ``[k]`` (or ``[k, ...]``
    when the values are per-particle tensors), ``k = len(names)``, in ``names`` order.
    """

    def __init__(
        self,
        cls: str,
        names: Sequence[str] | None = None,
        dtype: torch.dtype = torch.float64,
        ranges: Mapping[str, tuple[float, float]] | None = None,
    ):
        self.cls = normalise_class(cls)
        allowed = (*MATERIALS[self.cls].names, "density")
        names = tuple(MATERIALS[self.cls].names if names is None else names)
        bad = [n for n in names if n not in allowed]
        if bad or len(set(names)) != len(names) or not names:
            raise ValueError(
                f"Parameterisation: names {list(names)} invalid for class {self.cls} "
                f"(choose distinct names among {', '.join(allowed)})"
            )
        self.names: tuple[str, ...] = names
        ranges = dict(ranges or {})
        bad = [n for n in ranges if n not in names]
        if bad:
            raise ValueError(f"Parameterisation: ranges for {bad}, not among {list(names)}")
        specs = []
        for n in names:
            ps = spec(self.cls, n)
            if n in ranges:
                lo, hi = (float(v) for v in ranges[n])
                if not (0.0 < lo < hi if ps.scale == "log" else lo < hi):
                    raise ValueError(f"Parameterisation: range {ranges[n]} of {n} is empty")
                ps = replace(ps, low=lo, high=hi)
            specs.append(ps)
        self.specs = tuple(specs)
        self.dtype = dtype

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"Parameterisation({self.cls!r}, {list(self.names)!r})"

    def _u_of(self, ps, x):
        if ps.scale == "log":
            return (torch.log(x) - math.log(ps.low)) / (math.log(ps.high) - math.log(ps.low))
        return (x - ps.low) / (ps.high - ps.low)

    def _x_of(self, ps, u):
        if ps.scale == "log":
            return torch.exp(math.log(ps.low) + u * (math.log(ps.high) - math.log(ps.low)))
        return ps.low + u * (ps.high - ps.low)

    def to_theta(self, values: Mapping[str, Any] | MaterialParams) -> torch.Tensor:
        """``theta [k]`` (or ``[k, ...]``) of physical values (floats or tensors)."""
        if isinstance(values, MaterialParams):
            vals = dict(values.values)
            vals["density"] = values.density
        else:
            vals = dict(values)
        out = []
        for ps in self.specs:
            if ps.name not in vals:
                raise ValueError(f"to_theta: missing {ps.name} for class {self.cls}")
            x = torch.as_tensor(vals[ps.name], dtype=self.dtype)
            # Tolerance for values a float round-off outside a bound.
            tol = 1e-9 * max(abs(ps.low), abs(ps.high))
            if bool(torch.any((x < ps.low - tol) | (x > ps.high + tol) | ~torch.isfinite(x))):
                raise ValueError(
                    f"to_theta: {ps.name} = {x.tolist()} outside {ps.range_text()} "
                    f"(validate or clamp first)"
                )
            u = self._u_of(
                ps, x.clamp(min=max(ps.low, 1e-300) if ps.scale == "log" else ps.low, max=ps.high)
            ).clamp(EPS, 1.0 - EPS)
            out.append(torch.logit(u))
        return torch.stack(out)

    def from_theta(self, theta: torch.Tensor) -> dict[str, torch.Tensor]:
        """Physical values ``{name: tensor}`` of ``theta [k, ...]``, inside the ranges."""
        if theta.shape[0] != len(self.names):
            raise ValueError(
                f"from_theta: expected theta[{len(self.names)}], got {tuple(theta.shape)}"
            )
        return {ps.name: self._x_of(ps, torch.sigmoid(theta[i])) for i, ps in enumerate(self.specs)}

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper physical bounds ``[k]`` in ``names`` order."""
        lo = torch.tensor([ps.low for ps in self.specs], dtype=self.dtype)
        hi = torch.tensor([ps.high for ps in self.specs], dtype=self.dtype)
        return lo, hi
