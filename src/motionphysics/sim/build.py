"""Build a ready-to-run simulation from a prepared scene and a run config.

``build_simulation(sim_scene, run_cfg, material_sim, device)`` is what the run / fit
pipelines call: it makes the :class:`~.model.Model` (grid from the scene, per-particle
materials from ``material_sim``, gravity), the boundary program of the config, the
:class:`~.solver.Solver`, the initial state and the substep count, and returns a
:class:`Simulation`. It does not map physical to simulation values (``materials.simmap``
does) and does not render.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError
from motionphysics.sim.model import Model
from motionphysics.sim.rollout import Rollout, RolloutResult
from motionphysics.sim.solver import Solver, SolverConfig, auto_substeps
from motionphysics.sim.state import State


@dataclass
class Simulation:
    """Model, solver, initial state and time stepping of one run.

    Attributes:
        model: static model (grid, per-particle materials, boundary program).
        solver: the MLS-MPM solver over ``model``.
        state0: initial state (positions [m], initial velocity [m/s], F = I).
        substeps: substeps per frame.
        frame_dt: seconds between output frames [s].
        frames: default number of output frames T (frame 0 = initial state).
    """

    model: Model
    solver: Solver
    state0: State
    substeps: int
    frame_dt: float
    frames: int = 48
    _rollout: Rollout | None = field(default=None, repr=False)
    last: RolloutResult | None = field(default=None, repr=False)
    """The last :meth:`run`'s full result (``active`` [T, P] mask of particles a cut
    removed, ``wall_hits`` [{frame, wall}] of the domain walls material reached)."""

    @property
    def dt(self) -> float:
        """Substep [s]."""
        return self.frame_dt / self.substeps

    @property
    def rollout(self) -> Rollout:
        if self._rollout is None:
            self._rollout = Rollout(self.solver, self.substeps, self.frame_dt)
        return self._rollout

    def run(self, frames: int | None = None, return_velocities: bool = False):
        """Forward rollout without gradients, with the per-frame NaN / runaway check.

        Returns ``(xs, Fs)`` (or ``(xs, Fs, vs)``) numpy float32 arrays: positions [m]
        (T, P, 3), deformation gradients (T, P, 3, 3), velocities [m/s] (T, P, 3);
        T = ``frames`` (default ``self.frames``), frame 0 = the initial state.
        Raises :class:`~motionphysics.errors.SimulationError` on divergence.
        """
        res: RolloutResult = self.rollout.forward(
            self.state0,
            int(frames or self.frames),
            keep_velocities=return_velocities,
            keep_checkpoints=False,
        )
        self.last = res
        if return_velocities:
            return res.xs, res.Fs, res.vs
        return res.xs, res.Fs

    def set_initial_velocity(self, velocity: Any) -> None:
        """Set the initial velocity [m/s], (3,) or (P, 3)."""
        if hasattr(velocity, "detach"):
            velocity = velocity.detach().cpu().numpy()
        v = np.broadcast_to(np.asarray(velocity, np.float32), (self.model.particle_count, 3))
        self.state0.v.assign(np.ascontiguousarray(v))


def _to_numpy(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def build_simulation(
    sim_scene: Any,
    run_cfg: Any,
    material_sim: dict[str, Any],
    device: str = "cpu",
    requires_grad: bool = False,
    solver_config: SolverConfig | None = None,
    object_id: Any = None,
    contact_friction: float = 0.0,
) -> Simulation:
    """Everything needed to simulate ``sim_scene`` under ``run_cfg``.

    Args:
        sim_scene: ``scene.prepare.SimScene`` (particles [P,3] m, volumes [P] m^3,
            domain_lo [3] m, dx m, grid_dims; optional wall_lo / wall_hi [3] m, the
            material box whose faces are walls).
        run_cfg: ``config.RunConfig`` (uses ``sim`` (frames, frame_dt, substeps, gravity,
            initial_velocity), ``boundary_conditions`` and ``forces``).
        material_sim: sim-unit values, ``'class'`` (name or per-particle ids) plus
            parameters (scalars or per-particle tensors/arrays) incl. ``density``.
        device: ``"cpu"`` or ``"cuda"``.
        requires_grad: allocate gradient buffers on the parameter arrays and initial
            velocity (for :mod:`.bridge`).
        object_id: per-particle object index (P,) ints, or None: ``sim_scene.object_id``
            when the scene has one, else one object. Each object gets its own grid
            velocity field and contact between them (``kernels._make_contact_update``);
            per-object materials are per-particle arrays in ``material_sim`` (see
            :func:`~.model.per_object`).
        contact_friction: Coulomb coefficient between objects (0: frictionless).
    """
    sim_cfg = run_cfg.sim
    walls = None
    if getattr(sim_scene, "wall_lo", None) is not None:
        walls = (_to_numpy(sim_scene.wall_lo), _to_numpy(sim_scene.wall_hi))
    model = Model.from_particles(
        sim_scene.volumes,
        material_sim,
        _to_numpy(sim_scene.domain_lo),
        float(sim_scene.dx),
        sim_scene.grid_dims,
        gravity=sim_cfg.gravity,
        device=device,
        requires_grad=requires_grad,
        positions=sim_scene.particles,
        walls=walls,
        object_id=object_id if object_id is not None else getattr(sim_scene, "object_id", None),
        contact_friction=contact_friction,
    )
    # (the faces of the material box are walls even when the config names none:
    # BoundaryProgram adds them; ``boundary_conditions`` null -- the default ground not
    # yet resolved by the assembly -- is read as none)
    bcs = list(run_cfg.boundary_conditions or [])
    # (the static scene of a ``scene.region`` run: a level set at rest, scene.region)
    static = getattr(sim_scene, "static_collider", None)
    if bcs or run_cfg.forces or walls is not None or static is not None:
        try:
            from motionphysics.sim.boundary import BoundaryProgram
        except ImportError as err:  # pragma: no cover - the boundary module ships with sim
            raise UserInputError(
                "boundary_conditions/forces: the boundary module is not available in this build"
            ) from err
        model.boundary = BoundaryProgram.from_config(
            bcs, list(run_cfg.forces), model, static=static
        )
    if sim_cfg.substeps == "auto":
        substeps = auto_substeps(material_sim, model.dx, sim_cfg.frame_dt)
    else:
        substeps = int(sim_cfg.substeps)
    solver = Solver(model, solver_config)
    state0 = model.state(sim_scene.particles, sim_cfg.initial_velocity, requires_grad=requires_grad)
    return Simulation(model, solver, state0, substeps, float(sim_cfg.frame_dt), int(sim_cfg.frames))
