"""Differentiable MLS-MPM simulation on NVIDIA Warp (CPU and CUDA, one code path).

Public API (imported lazily, so ``import motionphysics.sim`` does not initialise Warp):

- :class:`Model` (static: grid, per-particle materials, boundary program) and
  :class:`State` (dynamic: x, v, C, F, plastic strain);
- :class:`Solver` with ``step(state_in, state_out, dt)``; :func:`auto_substeps`;
- :class:`Rollout` (checkpointed forward/backward, grad modes full / window /
  last_substep);
- :func:`build_simulation` → :class:`Simulation` (``run(frames) -> (xs, Fs)``);
- :func:`simulate` (bridge.py): the torch autograd entry point;
- several objects: ``Model.from_particles(..., object_id=[P])`` (or ``object_id=`` /
  ``sim_scene.object_id`` in :func:`build_simulation`) gives each object its own grid
  velocity field with multi-field contact; :func:`per_object` makes per-particle
  parameter arrays from one value per object.
"""

from __future__ import annotations

import importlib

__all__ = [
    "Model",
    "State",
    "Solver",
    "SolverConfig",
    "Grid",
    "auto_substeps",
    "stable_dt",
    "cfl_number",
    "Rollout",
    "RolloutResult",
    "Simulation",
    "build_simulation",
    "simulate",
    "PARAM_NAMES",
    "per_object",
]

_WHERE = {
    "Model": "model",
    "PARAM_NAMES": "model",
    "per_object": "model",
    "State": "state",
    "Solver": "solver",
    "SolverConfig": "solver",
    "Grid": "solver",
    "auto_substeps": "solver",
    "stable_dt": "solver",
    "cfl_number": "solver",
    "Rollout": "rollout",
    "RolloutResult": "rollout",
    "Simulation": "build",
    "build_simulation": "build",
    "simulate": "bridge",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"motionphysics.sim.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'motionphysics.sim' has no attribute {name!r}")
