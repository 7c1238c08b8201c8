"""The simulation phase of the assembly: the simulation context of a material under a
config, resolved once for every command.

The map context of :mod:`motionphysics.materials.simmap` (``dt = frame_dt / 512`` under
``substeps: auto``, ``frame_dt / n`` for a fixed ``n``), the simulation values
(:func:`sim_values`, torch float64 for every caller) and the substep count
(:func:`resolve_substeps`) make a :class:`SimResolution`; :func:`simulate_forward` runs
the forward rollout every command outputs. Re-exported by :mod:`motionphysics.assembly`;
writes no file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from motionphysics.config import RunConfig
from motionphysics.errors import SimulationError
from motionphysics.events import NullObserver

__all__ = [
    "SimResolution",
    "scene_scales",
    "map_context",
    "sim_values",
    "resolve_substeps",
    "resolve_simulation",
    "simulate_forward",
]


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


@dataclass(frozen=True)
class SimResolution:
    """The simulation a material gets under a config (what every command simulates)."""

    values: dict[str, float]
    """Simulation values (``materials.simmap``), density included, python floats."""
    context: Any
    """The :class:`~motionphysics.materials.simmap.SimContext` of the map."""
    substeps: int
    """Substeps per frame (``sim.substeps``, or the CFL choice under ``auto``)."""
    frame_dt: float
    """Seconds between output frames."""
    grid_dims: tuple[int, int, int]
    auto: bool
    """True when ``sim.substeps`` is ``auto`` (an optimiser re-resolves as it moves)."""
    notes: tuple[str, ...] = ()
    """Warning lines of the substep plan (the auto cap binding)."""

    @property
    def dt(self) -> float:
        """Substep [s]."""
        return self.frame_dt / self.substeps

    def record(self) -> dict[str, Any]:
        """The ``sim_context`` block of ``params.json``."""
        return {
            "dx": float(self.context.dx),
            "dt": self.frame_dt / self.substeps,
            "dt_map": float(self.context.dt),
            "substeps": int(self.substeps),
            "substeps_mode": "auto" if self.auto else "fixed",
            "frame_dt": float(self.frame_dt),
            "length": float(self.context.length),
            "grid_dims": [int(v) for v in self.grid_dims],
            # what the scene shows (materials.simmap, "What can be seen")
            "speed_met": float(self.context.speed),
            "thickness": float(self.context.thickness_or_length),
            "visible_strain": float(self.context.visible_strain),
            "visible_changes": [str(n) for n in self.notes],
        }


def scene_scales(cfg: RunConfig, sim_scene, closing_speed: float = 0.0) -> dict[str, float]:
    """What this scene shows of a material (``simmap.SimContext``'s scene fields).

    ``speed_met`` [m/s]: the largest speed the object meets: its fall under gravity onto
    the support below it (the highest upward-facing ``surface_collider`` under its lowest
    point, else the domain floor; at most ``g T`` over the run), combined with its initial
    velocity; imposed velocities (``force_particles_translation``, ``clamp_grid``); the
    rim speed of imposed rotations; impulses (their velocity change) and constant forces
    (acceleration x the window, within the run); ``closing_speed`` (several objects: the
    others' speeds). ``thickness`` [m]: the smallest of the principal extents of the
    particles and ``sqrt(V / L)`` (volume over length: a rod's diameter, a cube's side).
    ``duration`` [s]: the simulated time.
    """
    pts = np.asarray(_np(sim_scene.particles), dtype=np.float64)
    T = float(cfg.sim.frames) * float(cfg.sim.frame_dt)
    grav = np.asarray(cfg.sim.gravity, dtype=np.float64)
    g = float(np.linalg.norm(grav))
    speeds = [float(np.linalg.norm(cfg.sim.initial_velocity)) + float(closing_speed)]
    if g > 0:
        down = grav / g
        depth = pts @ down  # larger = lower
        lowest = float(depth.max())
        supports = []
        for bc in cfg.boundary_conditions or []:
            if getattr(bc, "type", None) != "surface_collider" or bc.mode == "cut":
                continue
            n = np.asarray(bc.normal, dtype=np.float64)
            n = n / max(float(np.linalg.norm(n)), 1e-12)
            if float(n @ -down) > 0.5:
                d = float(np.asarray(bc.point, dtype=np.float64) @ down)
                if d >= lowest - 1e-9:
                    supports.append(d)
        wall_lo = getattr(sim_scene, "wall_lo", None)
        wall_hi = getattr(sim_scene, "wall_hi", None)
        if wall_lo is not None and wall_hi is not None:
            lo, hi = _np(wall_lo).astype(np.float64), _np(wall_hi).astype(np.float64)
            corners = np.array(
                [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
            )
            supports.append(float((corners @ down).max()))
        h = max(0.0, min(supports) - lowest) if supports else 0.0
        fall = min(np.sqrt(2.0 * g * h), g * T)
        speeds[0] = float(np.hypot(speeds[0], fall))
    for item in list(cfg.forces or []) + list(cfg.boundary_conditions or []):
        kind = getattr(item, "type", None)
        if kind in ("force_particles_translation", "clamp_grid"):
            speeds.append(float(np.linalg.norm(item.velocity)))
        elif kind == "force_particles_rotation":
            c = np.asarray(item.center, dtype=np.float64)
            a = np.asarray(item.axis_direction, dtype=np.float64)
            a = a / max(float(np.linalg.norm(a)), 1e-12)
            r = pts - c
            rim = float(np.sqrt(np.max(np.sum(r * r, 1) - (r @ a) ** 2, initial=0.0)))
            speeds.append(abs(float(item.angular_velocity)) * rim)
        elif kind == "add_impulse":
            speeds.append(float(np.linalg.norm(item.force)))
        elif kind == "add_constant_force":
            window = max(0.0, min(float(item.end), T) - max(float(item.start), 0.0))
            if getattr(item, "unit", "seconds") == "substeps":
                window = T  # (a window in substeps: bounded by the run)
            speeds.append(float(np.linalg.norm(item.force)) * window)
    out: dict[str, float] = {"speed_met": max(speeds), "duration": T}
    if pts.shape[0] >= 4:
        centred = pts - pts.mean(0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        proj = centred @ vt.T
        ext = proj.max(0) - proj.min(0)
        length = float(ext.max())
        vols = getattr(sim_scene, "volumes", None)
        candidates = [float(ext.min())]
        if vols is not None and length > 0:
            candidates.append(float(np.sqrt(float(np.sum(_np(vols))) / length)))
        t = max(min(candidates), float(sim_scene.dx))
        out["thickness"] = min(t, float(np.max(pts.max(0) - pts.min(0))))
    return out


def map_context(
    cfg: RunConfig, sim_scene, density: float, n: int | None = None, closing_speed: float = 0.0
):
    """The sim-map context of a config and prepared scene (the one place it is made).

    ``dt`` of the map: ``frame_dt / n`` (``n``: the fixed ``sim.substeps``, or under
    ``auto`` the budget ``sim.max_substeps``); the scene's scales
    (:func:`scene_scales`) tell the map which values can be seen.
    """
    from motionphysics.materials.simmap import SimContext

    frame_dt = float(cfg.sim.frame_dt)
    pts = np.asarray(_np(sim_scene.particles))
    length = float(np.max(pts.max(0) - pts.min(0)))
    gravity = float(np.linalg.norm(np.asarray(cfg.sim.gravity, dtype=np.float64)))
    if n is None:
        n = _budget(cfg) if cfg.sim.substeps == "auto" else int(cfg.sim.substeps)
    return SimContext(
        dx=float(sim_scene.dx),
        dt=frame_dt / n,
        density=float(density),
        length=length,
        gravity=gravity,
        frame_dt=frame_dt,
        **scene_scales(cfg, sim_scene, closing_speed),
    )


def _budget(cfg: RunConfig) -> int:
    """Substeps per frame ``substeps: auto`` may spend (``sim.max_substeps``)."""
    return int(cfg.sim.max_substeps)


def sim_values(physical: Mapping[str, Any], cls: str, ctx) -> dict[str, Any]:
    """Physical values (floats, 0-dim or [P] tensors; density included) -> simulation values.

    The one evaluation of the sim map every command uses: inputs are cast to torch
    float64 (differentiably), so a forward-only run and an optimisation at the same
    physical values get the same simulation values to the last bit. Returns float64
    tensors (0-dim or [P]).
    """
    import torch

    from motionphysics.materials.simmap import physical_to_sim

    phys = {
        k: (
            v.to(torch.float64)
            if torch.is_tensor(v)
            else torch.tensor(float(v), dtype=torch.float64)
        )
        for k, v in physical.items()
        if k != "class"
    }
    return physical_to_sim(phys, ctx, cls=cls)


def _floats(values: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in values.items():
        a = _np(v).astype(np.float64)
        out[k] = float(a) if a.ndim == 0 else a
    return out


def resolve_substeps(cfg: RunConfig, cls: str, values: Mapping[str, Any], dx: float) -> int:
    """Substeps per frame for simulation ``values`` under ``cfg`` (``auto``: the CFL limit)."""
    if cfg.sim.substeps != "auto":
        return int(cfg.sim.substeps)
    from motionphysics.sim.solver import auto_substeps

    return int(auto_substeps({"class": cls, **_floats(values)}, float(dx), float(cfg.sim.frame_dt)))


def resolve_simulation(
    material, cfg: RunConfig, sim_scene, closing_speed: float = 0.0
) -> SimResolution:
    """Map context, simulation values and substeps of ``material`` (MaterialParams).

    The count comes from :func:`motionphysics.materials.simmap.plan_substeps`: a fixed
    ``sim.substeps`` that would make the material behave as another class is refused
    (one line saying what is needed); under ``auto`` the map spends up to the budget
    ``sim.max_substeps`` to simulate every visible value as asked and the run's count is
    the CFL count of the mapped values. ``notes`` (a visible change the budget forced,
    with its consequence) are returned for the caller to print.
    ``closing_speed``: several objects: the speed the others move at [m/s].
    """
    from motionphysics.materials.simmap import SCENE_KEYS, plan_substeps
    from motionphysics.sim.solver import auto_substeps

    ctx0 = map_context(cfg, sim_scene, float(material.density), closing_speed=closing_speed)
    plan = plan_substeps(
        material,
        cfg.sim.substeps,
        dx=float(ctx0.dx),
        frame_dt=float(cfg.sim.frame_dt),
        length=float(ctx0.length),
        gravity=float(ctx0.gravity),
        cfl_substeps=auto_substeps,
        cap=_budget(cfg),
        where="sim.substeps",
        scene={k: getattr(ctx0, k) for k in SCENE_KEYS},
    )
    ctx = plan.ctx
    phys = {"density": float(material.density), **{k: float(v) for k, v in material.values.items()}}
    values = {k: float(v) for k, v in _floats(sim_values(phys, material.cls, ctx)).items()}
    substeps = resolve_substeps(cfg, material.cls, values, float(sim_scene.dx))
    return SimResolution(
        values=values,
        context=ctx,
        substeps=substeps,
        frame_dt=float(cfg.sim.frame_dt),
        grid_dims=tuple(int(v) for v in sim_scene.grid_dims),
        auto=cfg.sim.substeps == "auto",
        notes=tuple(plan.notes),
    )


def _pinned(cfg: RunConfig, substeps: int) -> RunConfig:
    """``cfg`` with ``sim.substeps`` fixed to the resolved count (what build_simulation gets)."""
    return cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"substeps": int(substeps)})})


def _material_sim(material, values: Mapping[str, Any]) -> dict[str, Any]:
    """``build_simulation``'s material dict: the class (name, or per-particle ids of a
    :class:`SceneMaterial`) and the simulation values."""
    ids = getattr(material, "class_ids", None)
    return {"class": ids if ids is not None else material.cls, **values}


def simulate_forward(
    sim_scene,
    cfg: RunConfig,
    material,
    sim_values,
    device,
    frames: int,
    st,
    observer=None,
    *,
    initial_velocity=None,
    keep: dict[str, Any] | None = None,
):
    """Forward simulation of ``frames`` frames (what ``run``/``simulate``/``fit`` output).

    ``sim_values``: simulation values (of :func:`resolve_simulation`, or per particle
    for a :class:`SceneMaterial`); the substep count is resolved from them by
    :func:`resolve_substeps`. ``st``: a progress stage handle (``advance()``/``note()``).
    ``initial_velocity``: [P, 3] m/s per particle (several objects), or None (the
    config's ``sim.initial_velocity``). ``keep``: when given, ``keep["last"]`` receives
    the rollout's full result (``active`` [T, P], ``wall_hits``). Returns x [T, P, 3] m,
    F [T, P, 3, 3] and v [T, P, 3] m/s, float32 numpy (T = frames, frame 0 = the
    initial state), and the substeps.
    """
    from motionphysics.sim import build_simulation

    observer = observer or NullObserver()
    msim = _material_sim(material, sim_values)
    n = resolve_substeps(cfg, msim["class"], sim_values, float(sim_scene.dx))
    sim = build_simulation(sim_scene, _pinned(cfg, n), msim, device)
    if initial_velocity is not None:
        sim.set_initial_velocity(initial_velocity)
    st.note(f"simulate ({sim.substeps} substeps/frame)")
    ro = sim.rollout
    check = ro.check

    # The rollout calls ``check`` once per simulated frame; that is the per-frame hook
    # (sim/ has no observer of its own).
    def check_and_count(state, frame):
        check(state, frame)
        st.advance()
        observer.frame_simulated(int(frame), int(frames))

    ro.check = check_and_count
    st.advance()  # frame 0 is the initial state
    xs, Fs, vs = sim.run(frames, return_velocities=True)
    if keep is not None:
        keep["last"] = sim.last
    xs = np.asarray(_np(xs), dtype=np.float32)
    Fs = np.asarray(_np(Fs), dtype=np.float32)
    vs = np.asarray(_np(vs), dtype=np.float32)
    if not (np.isfinite(xs).all() and np.isfinite(Fs).all()):
        raise SimulationError(
            "the simulation produced non-finite positions or deformation "
            "gradients; lower sim.frame_dt or use more substeps"
        )
    return xs, Fs, vs, int(sim.substeps)
