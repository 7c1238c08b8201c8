"""What the optimisation loop optimises: parameters, their map to the simulator, the loss.

A :class:`Problem` ties together

- a *theta map* (physical values <-> unconstrained vector theta; the materials
  catalogue's ``Parameterisation`` in a real run),
- the values that stay fixed (density, parameters not optimised),
- ``to_sim``: the differentiable map from physical values to simulation values
  (``materials.simmap.physical_to_sim`` in a real run),
- a differentiable simulator (:class:`Simulator`: the MPM torch bridge in a real run),
- an optional differentiable renderer, and the loss.

Theta is held as one leaf tensor per parameter name (a 0-dim tensor for a scene-wide
parameter, ``[P]`` for a per-particle field) plus ``initial_velocity`` ``[3]`` [m/s]
when the initial velocity is optimised, so each leaf can have its own learning rate.
This module does no I/O and knows nothing of run directories.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import torch
from torch import Tensor

from motionphysics.losses.base import Loss, Prediction

__all__ = ["GradMode", "ParamSpec", "Problem", "Renderer", "Simulator", "ThetaMap", "VELOCITY"]

GradMode = Literal["full", "window", "last_substep"]
VELOCITY = "initial_velocity"
"""Leaf name of the optimised initial velocity (also its key in ``optimize.lr_per_param``)."""


@dataclass(frozen=True)
class ParamSpec:
    """How a parameter is reported and plotted."""

    name: str
    unit: str
    low: float
    high: float
    scale: Literal["log", "linear"] = "linear"


class ThetaMap(Protocol):
    """Physical values <-> unconstrained theta for an ordered list of names."""

    names: list[str]

    def to_theta(self, values: dict[str, float]) -> Tensor:
        """[k] unconstrained values for the physical ``values`` (k = len(names))."""
        ...

    def from_theta(self, theta: Tensor) -> dict[str, Tensor]:
        """Physical values from theta ``[k, ...]`` (each ``[...]``), differentiable."""
        ...


class Simulator(Protocol):
    """A differentiable rollout of the scene (the MPM bridge, or a test double)."""

    num_particles: int
    num_frames: int

    def simulate(
        self,
        sim_params: dict[str, Tensor],
        initial_velocity: Tensor | None,
        frames: Sequence[int],
        grad_mode: GradMode,
        window: int,
    ) -> tuple[Tensor, Tensor]:
        """Integrate every substep from frame 0 to ``max(frames)``.

        sim_params: simulation values, each a 0-dim tensor or ``[P]``.
        initial_velocity: ``[3]`` m/s or None (use the config's).
        Returns ``xs [S,P,3]`` and ``Fs [S,P,3,3]`` at ``frames`` (S = len(frames)),
        differentiable in ``sim_params`` and ``initial_velocity`` according to
        ``grad_mode`` (``window``: substeps before each frame gradients flow through).
        """
        ...


Renderer = Callable[[Tensor, Tensor], Tensor]
"""(xs [S,P,3], Fs [S,P,3,3]) -> rgb [S,H,W,3] in [0, 1], differentiable."""


@dataclass
class Problem:
    theta_map: ThetaMap
    """Map for the optimised parameter names (``theta_map.names``)."""
    initial: dict[str, float]
    """Starting physical values of the optimised names."""
    fixed: dict[str, float]
    """Physical values that are not optimised (density and the class's other parameters)."""
    to_sim: Callable[[dict[str, Tensor]], dict[str, Tensor]]
    """Physical values (optimised and fixed, tensors) -> simulation values, differentiable."""
    simulator: Simulator
    loss: Loss
    renderer: Renderer | None = None
    specs: dict[str, ParamSpec] = field(default_factory=dict)
    """Unit and range of each optimised name, for the log and the plots."""
    per_particle: tuple[str, ...] = ()
    """Names optimised as per-particle fields ([P] leaves) instead of scene-wide scalars."""
    initial_velocity: tuple[float, float, float] | None = None
    """Starting initial velocity [m/s] when it is optimised; None: not optimised."""
    range_notes: list[str] = field(default_factory=list)
    """One line per optimised parameter whose range was widened to hold its start value
    (written outside the handbook range), for the run to print."""

    def __post_init__(self):
        unknown = [n for n in self.per_particle if n not in self.theta_map.names]
        if unknown:
            raise ValueError(f"per-particle names {unknown} are not optimised names")
        if self.loss.needs_render and self.renderer is None:
            raise ValueError(
                f"loss {self.loss.name!r} needs rendered frames but no renderer was given"
            )

    # ----------------------------------------------------------------- theta leaves
    @property
    def leaf_names(self) -> list[str]:
        names = list(self.theta_map.names)
        if self.initial_velocity is not None:
            names.append(VELOCITY)
        return names

    def initial_theta(self) -> dict[str, Tensor]:
        """Fresh leaf tensors (requires_grad) at the starting values."""
        base = self.theta_map.to_theta({n: self.initial[n] for n in self.theta_map.names})
        base = base.detach().to(torch.float32)
        p = self.simulator.num_particles
        leaves: dict[str, Tensor] = {}
        for i, n in enumerate(self.theta_map.names):
            v = base[i].clone()
            if n in self.per_particle:
                v = v.expand(p).clone()
            leaves[n] = v.requires_grad_(True)
        if self.initial_velocity is not None:
            leaves[VELOCITY] = torch.tensor(
                self.initial_velocity, dtype=torch.float32
            ).requires_grad_(True)
        return leaves

    # ------------------------------------------------------------------ the maps
    def physical(self, theta: dict[str, Tensor]) -> dict[str, Tensor]:
        """Physical values of the optimised names (0-dim or [P]), differentiable."""
        names = self.theta_map.names
        if not self.per_particle:
            vec = torch.stack([theta[n] for n in names])  # [k]
            return self.theta_map.from_theta(vec)
        p = self.simulator.num_particles
        mat = torch.stack([theta[n].expand(p) for n in names])  # [k, P]
        out = self.theta_map.from_theta(mat)
        return {n: (out[n] if n in self.per_particle else out[n][0]) for n in names}

    def all_physical(self, theta: dict[str, Tensor]) -> dict[str, Tensor]:
        # float64: a fixed value (nu = 0.3) must reach the sim map exactly as a forward
        # command gives it, or the two would simulate different materials.
        values = {k: torch.tensor(v, dtype=torch.float64) for k, v in self.fixed.items()}
        values.update(self.physical(theta))
        return values

    def sim_values(self, theta: dict[str, Tensor]) -> dict[str, Tensor]:
        return self.to_sim(self.all_physical(theta))

    # ---------------------------------------------------------------- forward pass
    def forward(
        self,
        theta: dict[str, Tensor],
        frames: Sequence[int],
        grad_mode: GradMode,
        window: int,
        timings: dict[str, float],
    ) -> Prediction:
        """Simulate (and render when the loss needs pixels) the supervised ``frames``."""
        t0 = time.perf_counter()
        sim = self.sim_values(theta)
        xs, Fs = self.simulator.simulate(sim, theta.get(VELOCITY), frames, grad_mode, window)
        t1 = time.perf_counter()
        timings["simulate"] = t1 - t0
        rgb = None
        if self.loss.needs_render:
            assert self.renderer is not None  # checked in __post_init__
            rgb = self.renderer(xs, Fs)
        timings["render"] = time.perf_counter() - t1
        return Prediction(frame_indices=tuple(int(f) for f in frames), xs=xs, Fs=Fs, rgb=rgb)

    # ------------------------------------------------------------------- reporting
    def report(self, theta: dict[str, Tensor]) -> tuple[dict, dict]:
        """JSON-able physical and simulation values: floats for scene-wide values,
        ``{"mean", "min", "max"}`` for per-particle fields, a list for the velocity."""
        with torch.no_grad():
            phys = self.all_physical(theta)
            sim = self.to_sim(phys)
        out_p = {k: _summary(v) for k, v in phys.items()}
        out_s = {k: _summary(v) for k, v in sim.items()}
        if VELOCITY in theta:
            out_p[VELOCITY] = [float(x) for x in theta[VELOCITY].detach()]
        return out_p, out_s


def _summary(v) -> float | dict[str, float]:
    t = torch.as_tensor(v).detach()
    if t.numel() == 1:
        return float(t.reshape(()))
    t = t.double()
    return {"mean": float(t.mean()), "min": float(t.min()), "max": float(t.max())}
