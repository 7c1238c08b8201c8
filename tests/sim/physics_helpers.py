"""Scene builders and a plain rollout loop for the physics validation tests (test_physics_*).

The tests drive the simulator through its public pieces only (CONTRACTS.md, "sim"):
``Model.from_particles``, ``Model.state``, ``Solver.step`` and
``BoundaryProgram.from_config``; materials are given directly in simulation units.
Particles sit on a cell-centred lattice of spacing ``h`` (each particle owns an h^3
volume), so the material's geometric extent is the particle extent plus h/2 each side.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# The test modules import this file and reference_data.py by name.
_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)


def box_lattice(lo, hi, h: float) -> np.ndarray:
    """Cell-centred lattice points [m] (N, 3) filling the box [lo, hi] with spacing ~h.

    The count per axis is round(extent / h) and the spacing is adjusted to tile the box
    exactly, so the particles' volumes sum to the box volume.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    counts = np.maximum(1, np.round((hi - lo) / h).astype(int))
    axes = [lo[a] + (np.arange(counts[a]) + 0.5) * (hi[a] - lo[a]) / counts[a] for a in range(3)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([c.ravel() for c in g], axis=1)


def box_volumes(lo, hi, count: int) -> np.ndarray:
    """Equal particle volumes [m^3] (count,) summing to the box volume."""
    vol = float(np.prod(np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)))
    return np.full(count, vol / count)


def sphere_lattice(center, radius: float, h: float) -> np.ndarray:
    """Cell-centred lattice points [m] inside a sphere; each stands for an h^3 volume."""
    c = np.asarray(center, dtype=np.float64)
    pts = box_lattice(c - radius, c + radius, h)
    return pts[np.linalg.norm(pts - c, axis=1) <= radius]


@dataclass
class Frames:
    """Per-frame host copies of a simulation: times [s] (T,), x, v [m, m/s] (T, P, 3),
    F [-] (T, P, 3, 3), ep [-] (T, P)."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    F: np.ndarray
    ep: np.ndarray


def run(
    positions: np.ndarray,
    volumes: np.ndarray,
    material: dict[str, Any],
    *,
    domain_lo,
    dx: float,
    grid_dims,
    dt: float,
    substeps_per_frame: int,
    frames: int,
    gravity=(0.0, 0.0, -9.8),
    velocity=None,
    boundary_conditions: list[dict] | None = None,
    threads: int | None = None,
) -> Frames:
    """Simulate ``frames`` frames of ``substeps_per_frame`` substeps of ``dt`` [s] on CPU.

    ``material`` is a sim-unit dict (``'class'`` + parameters); ``velocity`` is (3,) or
    (P, 3) [m/s]; ``boundary_conditions`` are config dicts (``config.BoundaryCondition``)
    turned into a ``BoundaryProgram``. Frame 0 is the initial state. Raises
    ``RuntimeError`` when the state turns non-finite (a physics test must not silently
    compare NaNs).
    """
    from pydantic import TypeAdapter

    from motionphysics.config import BoundaryCondition
    from motionphysics.sim.model import Model
    from motionphysics.sim.solver import Solver, SolverConfig

    model = Model.from_particles(
        volumes, material, domain_lo=domain_lo, dx=dx, grid_dims=grid_dims, gravity=gravity
    )
    if boundary_conditions:
        from motionphysics.sim.boundary import BoundaryProgram

        adapter = TypeAdapter(BoundaryCondition)
        bcs = [adapter.validate_python(bc) for bc in boundary_conditions]
        model.boundary = BoundaryProgram.from_config(bcs, [], model, x0=positions)
    solver = Solver(model, SolverConfig(threads=threads))
    a = model.state(positions, velocity)
    b = model.state(positions, velocity)
    out = {k: [] for k in ("x", "v", "F", "ep")}

    def record(s) -> None:
        h = s.numpy()
        for k in out:
            out[k].append(h[k])

    record(a)
    substep = 0
    try:
        for frame in range(frames):
            for _ in range(substeps_per_frame):
                solver.step(a, b, dt, t=substep * dt, substep=substep)
                a, b = b, a
                substep += 1
            record(a)
            if not np.all(np.isfinite(out["x"][-1])):
                raise RuntimeError(f"non-finite particle positions at frame {frame + 1}")
    finally:
        solver.close()
    t = np.arange(frames + 1) * substeps_per_frame * dt
    return Frames(t=t, **{k: np.stack(v) for k, v in out.items()})


def zero_crossing_period(t: np.ndarray, y: np.ndarray) -> float:
    """Mean period [s] of an oscillation of ``y`` about 0, from linearly interpolated zero
    crossings (needs at least three crossings)."""
    s = np.sign(y)
    idx = np.nonzero(s[:-1] * s[1:] < 0)[0]
    if idx.size < 3:
        raise AssertionError(f"only {idx.size} zero crossings: no oscillation measured")
    tc = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    return 2.0 * float(np.mean(np.diff(tc)))
