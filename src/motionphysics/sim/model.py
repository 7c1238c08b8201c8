"""Static simulation model (Newton style): grid geometry, particle volumes, materials.

The :class:`Model` is built once and never changes during a rollout (its material
arrays may carry gradients). Every particle carries its material class id and its
own parameter values, so one scene can mix classes. What changes per substep lives in
:class:`~.state.State`; grid scratch is owned by :class:`~.solver.Solver`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.errors import UserInputError
from motionphysics.runtime import init_warp

PARAM_NAMES = ("E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n", "density")
"""Per-particle material parameter arrays of a model (simulation units)."""

CLASS_PARAMS: dict[str, tuple[str, ...]] = {
    "elastic": ("E", "nu"),
    "plasticine": ("E", "nu", "tau_Y"),
    "metal": ("E", "nu", "tau_Y"),
    "foam": ("E", "nu", "eta"),
    "sand": ("E", "nu", "theta_fric"),
    "newtonian": ("mu", "kappa"),
    "non_newtonian": ("mu", "kappa", "tau_Y", "eta"),
}
"""Parameters each class needs (density always; ``n`` defaults to 1, foam's ``tau_Y``
to ``constitutive.FOAM_DEFAULT_YIELD_FRACTION * E``)."""

# Harmless fill values for parameters a particle's class does not read (keeps every
# kernel argument finite, e.g. lame(E, nu) is evaluated by no class that lacks E).
_FILL = {
    "E": 1.0,
    "nu": 0.3,
    "tau_Y": 0.0,
    "eta": 0.0,
    "theta_fric": 30.0,
    "mu": 0.0,
    "kappa": 0.0,
    "n": 1.0,
    "density": 1.0,
}


def class_ids(value: Any, count: int) -> np.ndarray:
    """Material class ids (int32, shape (count,)) from a name, an id, or per-particle ids/names."""
    if isinstance(value, str):
        if value not in MATERIAL_CLASSES:
            raise UserInputError(
                f"material.class: expected one of {', '.join(MATERIAL_CLASSES)}, got {value!r}"
            )
        return np.full(count, MATERIAL_CLASSES.index(value), dtype=np.int32)
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    arr = np.asarray(value)
    if arr.dtype.kind in "US":
        return np.array([class_ids(str(s), 1)[0] for s in arr.reshape(-1)], dtype=np.int32).reshape(
            arr.shape
        )
    arr = np.broadcast_to(arr.astype(np.int64), (count,)) if arr.ndim == 0 else arr.astype(np.int64)
    if arr.shape != (count,):
        raise UserInputError(
            f"material.class: expected one id or {count} per-particle ids, got shape {arr.shape}"
        )
    if arr.min() < 0 or arr.max() >= len(MATERIAL_CLASSES):
        raise UserInputError(f"material.class: ids must be in [0, {len(MATERIAL_CLASSES) - 1}]")
    return arr.astype(np.int32)


def _per_particle(name: str, value: Any, count: int) -> np.ndarray:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(count, float(arr))
    if arr.shape != (count,):
        raise UserInputError(
            f"material.{name}: expected a scalar or {count} per-particle values, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise UserInputError(f"material.{name}: values must be finite")
    return arr.astype(np.float32)


def material_arrays(
    material: dict[str, Any], count: int
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Validate a sim-unit material dict into (class ids, per-particle float32 parameter arrays).

    ``material`` maps ``'class'`` (name, id, or per-particle ids) and parameter names of
    :data:`PARAM_NAMES` to scalars or per-particle arrays/tensors. Each class present needs
    its :data:`CLASS_PARAMS` and ``density``.
    """
    if "class" not in material:
        raise UserInputError("material.class: missing (expected a material class name or ids)")
    unknown = set(material) - set(PARAM_NAMES) - {"class"}
    if unknown:
        raise UserInputError(
            f"material: unknown sim parameter(s) {sorted(unknown)}; expected {PARAM_NAMES}"
        )
    ids = class_ids(material["class"], count)
    params = {name: np.full(count, _FILL[name], dtype=np.float32) for name in PARAM_NAMES}
    given = {k: _per_particle(k, v, count) for k, v in material.items() if k != "class"}
    present = sorted(set(ids.tolist()))
    for cid in present:
        cname = MATERIAL_CLASSES[cid]
        sel = ids == cid
        needed = (*CLASS_PARAMS[cname], "density")
        for name in needed:
            if name not in given:
                raise UserInputError(f"material.{name}: required for class {cname!r} but not given")
            params[name][sel] = given[name][sel]
        for name in ("n", "tau_Y"):
            if name in given:
                params[name][sel] = given[name][sel]
        if cname == "foam" and "tau_Y" not in given:
            from motionphysics.sim.constitutive import FOAM_DEFAULT_YIELD_FRACTION

            params["tau_Y"][sel] = FOAM_DEFAULT_YIELD_FRACTION * params["E"][sel]
    _check_ranges(ids, params)
    return ids, params


def _check_ranges(ids: np.ndarray, params: dict[str, np.ndarray]) -> None:
    def bad(name: str, sel: np.ndarray, ok: np.ndarray, what: str) -> None:
        if np.any(sel & ~ok):
            raise UserInputError(f"material.{name}: expected {what}")

    uses_e = np.isin(ids, [0, 1, 2, 3, 4])
    bad("density", np.ones_like(ids, bool), params["density"] > 0, "a positive density")
    bad("E", uses_e, params["E"] > 0, "E > 0")
    bad("nu", uses_e, (params["nu"] > -1) & (params["nu"] < 0.5), "-1 < nu < 0.5")
    bad("tau_Y", np.ones_like(ids, bool), params["tau_Y"] >= 0, "tau_Y >= 0")
    bad("eta", np.ones_like(ids, bool), params["eta"] >= 0, "eta >= 0")
    bad(
        "theta_fric",
        ids == 4,
        (params["theta_fric"] >= 0) & (params["theta_fric"] < 90),
        "a friction angle in [0, 90) degrees",
    )
    fluid = np.isin(ids, [5, 6])
    bad("mu", fluid, params["mu"] >= 0, "mu >= 0")
    bad("mu", ids == 6, params["mu"] > 0, "mu > 0 (shear modulus of the non-Newtonian fluid)")
    bad("kappa", fluid, params["kappa"] > 0, "kappa > 0")
    bad("n", ids == 6, params["n"] > 0, "a power-law index n > 0")


def stencil_box(domain_lo, dx: float, grid_dims) -> tuple[tuple, tuple]:
    """The grid's stencil-safe interior ``[lo + 2 dx, lo + (n - 3) dx]`` [m]: a particle at
    grid coordinate g needs its quadratic stencil ``floor(g - 0.5) + {0,1,2}`` in ``[0, n)``;
    ``2 <= g <= n - 3`` leaves one spare cell each side."""
    lo = tuple(float(domain_lo[a]) + 2.0 * dx for a in range(3))
    hi = tuple(float(domain_lo[a]) + (int(grid_dims[a]) - 3) * dx for a in range(3))
    return lo, hi


def _check_walls(walls: Any, glo, dx: float, dims) -> tuple[tuple, tuple]:
    lo = np.asarray(walls[0], dtype=np.float64).reshape(3)
    hi = np.asarray(walls[1], dtype=np.float64).reshape(3)
    slo, shi = (np.asarray(b) for b in stencil_box(glo, dx, dims))
    tol = 1e-4 * dx
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
        raise UserInputError(f"sim.domain: expected finite walls with lo < hi, got {lo}, {hi}")
    if np.any(lo < slo - tol) or np.any(hi > shi + tol):
        raise UserInputError(
            f"sim.domain: walls {lo.tolist()}..{hi.tolist()} must lie at least 2 cells inside "
            f"the grid {slo.tolist()}..{shi.tolist()} (the solver's padding)"
        )
    return tuple(float(a) for a in np.maximum(lo, slo)), tuple(
        float(a) for a in np.minimum(hi, shi)
    )


def _object_ids(value: Any, count: int) -> tuple[np.ndarray, int]:
    """Per-particle object indices (int32 (count,)) and the object count."""
    if value is None:
        return np.zeros(count, dtype=np.int32), 1
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    arr = np.asarray(value)
    if arr.ndim == 0:
        arr = np.full(count, int(arr))
    if arr.shape != (count,) or arr.dtype.kind not in "iub":
        raise UserInputError(
            f"objects: expected {count} integer object ids, got shape {arr.shape} ({arr.dtype})"
        )
    if arr.min() < 0:
        raise UserInputError("objects: object ids must be >= 0")
    n = int(arr.max()) + 1
    if n > MAX_OBJECTS:
        raise UserInputError(f"objects: at most {MAX_OBJECTS} objects, got {n}")
    return arr.astype(np.int32), n


def per_object(object_id: Any, values: Sequence[Any]) -> Any:
    """Per-particle array (P,) from one value per object: ``values[object_id[p]]``.

    ``values``: floats / 0-dim tensors, one per object. With torch tensors the result is a
    differentiable float32 tensor (gradients reach each object's value: what the fit needs
    for one parameter vector per object); else a float32 ndarray.
    """
    if hasattr(object_id, "numpy") and not hasattr(object_id, "detach"):
        object_id = object_id.numpy()
    if any(hasattr(v, "detach") for v in values):
        import torch

        oid = torch.as_tensor(np.asarray(object_id), dtype=torch.long)
        stacked = torch.stack([torch.as_tensor(v, dtype=torch.float32).reshape(()) for v in values])
        return stacked[oid]
    return np.asarray(values, dtype=np.float32)[np.asarray(object_id, dtype=np.int64)]


MAX_OBJECTS = 8
"""Most objects (grid velocity fields) one simulation may have."""


@dataclass
class Model:
    """Static data of one simulation.

    Attributes:
        device: Warp device, ``"cpu"`` or ``"cuda"`` (``"cuda:0"``).
        particle_count: number of particles P.
        domain_lo: world position of grid node (0, 0, 0) [m], shape (3,).
        dx: grid spacing [m].
        grid_dims: number of grid NODES per axis (nx, ny, nz).
        gravity: gravitational acceleration [m/s^2], shape (3,).
        volume: rest volume of particles [m^3], shape (P,), dtype float32.
        material_class: class id of particles (config.MATERIAL_CLASSES order),
            shape (P,), dtype int32.
        E, nu, tau_Y, eta, theta_fric, mu, kappa, n, density: per-particle material
            parameters in simulation units, shape (P,), dtype float32 (E, tau_Y, mu of
            HB, kappa [Pa]; nu, eta, n [-]; theta_fric [degrees]; mu of a Newtonian
            fluid [Pa s]; density [kg/m^3]; particle mass = density * volume).
            With ``requires_grad`` they carry ``.grad`` buffers.
        boundary: optional ``sim.boundary.BoundaryProgram`` (hooks called every substep).
        particle_x0: initial particle positions [m], (P, 3) float32 ndarray, or None
            (read by ``BoundaryProgram.from_config`` for its particle selections).
        walls: the box material may occupy, ``((xlo, ylo, zlo), (xhi, yhi, zhi))`` [m]
            (``sim.domain``; its faces are walls), or None (legacy: the box
            ``[lo + 2 dx, lo + (n - 3) dx]``, the stencil-safe interior of the grid). G2P
            projects particles back onto it, and ``bounding_box`` constrains the grid
            nodes on or beyond its faces. It must lie within the stencil-safe interior
            (the solver's padding cells lie outside it). See :attr:`wall_box`.
        object_id: object index of each particle (0 .. num_objects - 1), shape (P,),
            dtype int32. Each object has its own grid velocity field and objects meet
            through the contact of ``sim.contact`` (one object: the single-field solver).
        contact_friction: Coulomb coefficient between objects [-] (0: frictionless).
    """

    device: str
    particle_count: int
    domain_lo: tuple[float, float, float]
    dx: float
    grid_dims: tuple[int, int, int]
    gravity: tuple[float, float, float]
    volume: Any
    material_class: Any
    params: dict[str, Any] = field(default_factory=dict)
    boundary: Any = None
    particle_x0: Any = None
    walls: Any = None
    object_id: Any = None
    num_objects: int = 1
    contact_friction: float = 0.0

    def __getattr__(self, name: str):
        # E, nu, ... read as attributes (Newton style); ``params`` holds them.
        params = self.__dict__.get("params")
        if params is not None and name in params:
            return params[name]
        raise AttributeError(name)

    @property
    def domain_hi(self) -> tuple[float, float, float]:
        """World position of the last grid node [m]."""
        return tuple(self.domain_lo[a] + (self.grid_dims[a] - 1) * self.dx for a in range(3))

    @property
    def wall_box(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """``(lo, hi)`` [m] of the box particles are kept in (``walls``, or the legacy box)."""
        if self.walls is not None:
            lo, hi = self.walls
            return tuple(float(a) for a in lo), tuple(float(a) for a in hi)  # type: ignore[return-value]
        return stencil_box(self.domain_lo, self.dx, self.grid_dims)

    @property
    def requires_grad(self) -> bool:
        return bool(self.params["E"].requires_grad)

    @classmethod
    def from_particles(
        cls,
        volumes: Any,
        material: dict[str, Any],
        domain_lo: Any,
        dx: float,
        grid_dims: Any,
        gravity: Any = (0.0, 0.0, -9.8),
        device: str = "cpu",
        requires_grad: bool = False,
        positions: Any = None,
        walls: Any = None,
        object_id: Any = None,
        contact_friction: float = 0.0,
    ) -> Model:
        """Build a model from rest volumes [m^3] (P,) and a sim-unit material dict.

        ``material``: ``'class'`` (name / id / per-particle ids) plus parameters of
        :data:`PARAM_NAMES` as scalars or per-particle arrays/tensors (see
        :func:`material_arrays`). ``positions`` [m] (P, 3): initial positions kept as
        ``particle_x0`` (needed by boundary programs). ``walls``: the material box
        ``(lo (3,), hi (3,))`` [m] (see the class docstring; None: legacy box).
        ``object_id``: per-particle object index (P,) ints (None: one object);
        ``contact_friction``: Coulomb coefficient of object-object contact.
        """
        wp = init_warp()
        if hasattr(volumes, "detach"):
            volumes = volumes.detach().cpu().numpy()
        vol = np.asarray(volumes, dtype=np.float32).reshape(-1)
        count = vol.shape[0]
        if count == 0:
            raise UserInputError("scene: no particles to simulate")
        if np.any(~np.isfinite(vol)) or np.any(vol <= 0):
            raise UserInputError("scene: particle volumes must be positive and finite")
        dims = tuple(int(d) for d in grid_dims)
        if len(dims) != 3 or min(dims) < 5:
            raise UserInputError(f"sim.grid: need at least 5 grid nodes per axis, got {dims}")
        if not dx > 0:
            raise UserInputError(f"sim.grid: grid spacing must be positive, got {dx}")
        ids, params = material_arrays(material, count)
        x0 = None
        if positions is not None:
            if hasattr(positions, "detach"):
                positions = positions.detach().cpu().numpy()
            x0 = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
            if x0.shape[0] != count:
                raise UserInputError(f"scene: {x0.shape[0]} positions for {count} particle volumes")
        glo = tuple(float(a) for a in np.asarray(domain_lo, dtype=np.float64).reshape(3))
        wall_pair = None
        if walls is not None:
            wall_pair = _check_walls(walls, glo, float(dx), dims)
        oid, nobj = _object_ids(object_id, count)
        if not (math.isfinite(float(contact_friction)) and float(contact_friction) >= 0):
            raise UserInputError(
                f"sim.contact.friction: expected a finite value >= 0, got {contact_friction}"
            )
        return cls(
            device=device,
            particle_count=count,
            domain_lo=glo,
            dx=float(dx),
            grid_dims=dims,  # type: ignore[arg-type]
            gravity=tuple(float(g) for g in np.asarray(gravity, dtype=np.float64).reshape(3)),
            volume=wp.array(vol, dtype=float, device=device),
            material_class=wp.array(ids, dtype=wp.int32, device=device),
            params={
                name: wp.array(
                    params[name], dtype=float, device=device, requires_grad=requires_grad
                )
                for name in PARAM_NAMES
            },
            particle_x0=x0,
            walls=wall_pair,
            object_id=wp.array(oid, dtype=wp.int32, device=device),
            num_objects=nobj,
            contact_friction=float(contact_friction),
        )

    def set_param(self, name: str, values: Any) -> None:
        """Overwrite parameter ``name`` with a scalar or per-particle values (keeps the array)."""
        arr = _per_particle(name, values, self.particle_count)
        self.params[name].assign(arr)

    def zero_grad(self) -> None:
        for a in self.params.values():
            if a.grad is not None:
                a.grad.zero_()

    def state(self, positions: Any, velocity: Any = None, requires_grad: bool = False):
        """Rest state (F = I, C = 0) at ``positions`` [m] (P, 3) with ``velocity`` [m/s] (3,) or (P, 3)."""
        from motionphysics.sim.state import State

        if hasattr(positions, "detach"):
            positions = positions.detach().cpu().numpy()
        if velocity is not None and hasattr(velocity, "detach"):
            velocity = velocity.detach().cpu().numpy()
        pos = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        if pos.shape[0] != self.particle_count:
            raise UserInputError(
                f"scene: {pos.shape[0]} particle positions for a model of {self.particle_count} particles"
            )
        return State.from_numpy(pos, velocity, device=self.device, requires_grad=requires_grad)
