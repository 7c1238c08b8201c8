"""Boundary conditions and external forces of the MPM solver (the paper's module table).

A :class:`BoundaryProgram` is built once from the run config's ``boundary_conditions``
and ``forces`` lists (``config.BoundaryCondition`` / ``config.Force`` models), the grid
geometry and the INITIAL particle positions (particle selections by box / sphere / all
are computed once, at time 0, and stored as masks). The solver calls three hooks per
substep (CONTRACTS.md, "sim"):

* ``apply_pre_p2g(model, state_in, t, substep, dt)`` -- imposed velocities of
  translated / rotated particles and v = 0 of frozen ones, so P2G scatters them;
* ``apply_grid(model, grid_v, t, substep, dt, region=None)`` -- grid conditions after the
  grid update (optionally on the active sub-box of nodes only):
  ``clamp_grid``, ``bounding_box``, ``surface_collider`` (sticky / slip / frictional / cut),
  and the static scene of a ``scene.region`` run (a level set at rest:
  ``scene.region.StaticCollider``, given to :meth:`BoundaryProgram.build` as ``static``);
* ``apply_post_g2p(model, state_in, state_out, t, substep, dt)`` -- additive forces
  (``add_constant_force``: an acceleration ``force`` [m/s^2], v += dt a, x += dt^2 a;
  ``add_impulse``: a velocity change ``force`` [m/s] delivered within the substep that
  holds ``start``, or evenly over ``[start, end)`` when ``end`` is given), imposed motion
  (``force_particles_translation`` / ``_rotation``: x = x_in moved by the imposed motion),
  frozen particles of ``release_particles`` (held at x_in) and removal by ``cut``.

``t`` is the time at the start of the substep [s]; an entry acts in substep s when
``start <= t < end`` (``unit: substeps``: ``start <= s < end``).

Gradients: every hook modifies arrays in place, which a plain ``wp.Tape`` would
differentiate wrongly (Warp's adjoints assume each array element is written once). So
when a tape records, a hook saves its inputs, launches with ``record_tape=False`` and
records an exact custom adjoint (``tape.record_func``) that maps the incoming gradient
of the modified arrays through the kernel's adjoint and accumulates the gradients of
the learned parameters (:attr:`BoundaryProgram.params`: force magnitudes, imposed
velocities, friction coefficients, clamp velocities).

This module does not integrate particles, own grids, or know about materials.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from motionphysics.config import (
    AddConstantForce,
    AddImpulse,
    BoundaryCondition,
    BoundingBox,
    ClampGrid,
    Force,
    ForceParticlesRotation,
    ForceParticlesTranslation,
    ReleaseParticles,
    SurfaceCollider,
)
from motionphysics.errors import UserInputError
from motionphysics.runtime import init_warp
from motionphysics.sim.state import copy_array

__all__ = ["BoundaryParam", "BoundaryProgram", "particle_bounds"]

_TIME_EPS = 1.0e-3
"""Window tests compare ``t + _TIME_EPS * dt`` so a substep starting exactly at a window
edge (up to round-off of ``substep * dt``) is classified the same on every machine."""

_NO_END = 1.0e9  # config default of `end`: "never ends" (a null `end` is read as this)


def particle_bounds(domain_lo: Sequence[float], dx: float, grid_dims: Sequence[int]):
    """Box [m] that particle positions are clamped to (same rule as sim-core's G2P).

    A particle at grid coordinate g needs its quadratic stencil ``floor(g - 0.5) + {0,1,2}``
    inside ``[0, n)``; keeping ``2 <= g <= n - 3`` leaves one spare cell each side.
    Returns ``(x_min, x_max)``, two tuples of 3 floats.
    """
    lo = [float(a) for a in domain_lo]
    x_min = tuple(lo[a] + 2.0 * dx for a in range(3))
    x_max = tuple(lo[a] + (int(grid_dims[a]) - 3) * dx for a in range(3))
    return x_min, x_max


@dataclass(frozen=True)
class BoundaryParam:
    """One learnable boundary/force parameter.

    Attributes:
        name: ``"forces[0].force"``, ``"boundary_conditions[1].friction"``, ...
        array: Warp storage, shape (1,), dtype vec3 (size 3) or float32 (size 1), with
            ``requires_grad``; kernels read ``array[0]`` and their adjoints fill ``array.grad``.
        size: 3 or 1.
        unit: physical unit of the value (``"m/s^2"``, ``"m/s"``, ``"rad/s"``, ``"-"``).
    """

    name: str
    array: Any
    size: int
    unit: str

    def value(self) -> np.ndarray:
        """Current value, float32 shape (size,)."""
        return self.array.numpy().reshape(self.size).astype(np.float32)

    def grad(self) -> np.ndarray:
        """Accumulated gradient, float32 shape (size,) (zeros when none was computed)."""
        if self.array.grad is None:
            return np.zeros(self.size, dtype=np.float32)
        return self.array.grad.numpy().reshape(self.size).astype(np.float32)


# --------------------------------------------------------------------------- helpers


def _active_tape():
    import warp._src.context as ctx  # the tape Warp is recording on, if any

    return ctx.runtime.tape


class _BufferPool:
    """Free lists of Warp arrays by (shape, dtype, device), bounded in bytes.

    A recorded launch takes a buffer for its saved source and gives it back once its
    adjoint has run; the adjoint takes and gives back its scratch. A rollout that records
    the same substeps every iteration then allocates its buffers once (fresh arrays cost
    page faults). The active region, and so the shapes, drift as the material moves:
    when the free buffers exceed ``cap`` bytes the least recently returned shapes are
    dropped, so the pool cannot grow without bound.
    """

    def __init__(self, cap: int):
        self.cap = int(cap)
        self._free: OrderedDict = OrderedDict()  # key -> [arrays], least recent first
        self._bytes = 0
        self._lock = threading.Lock()

    @staticmethod
    def _key(shape, dtype, device):
        return (tuple(int(n) for n in shape), dtype, str(device))

    def take(self, shape, dtype, device):
        """An array of ``shape`` (contents undefined)."""
        key = self._key(shape, dtype, device)
        with self._lock:
            free = self._free.get(key)
            if free:
                buf = free.pop()
                self._bytes -= buf.capacity
                return buf
        return init_warp().empty(key[0], dtype=dtype, device=device)

    def give(self, buf) -> None:
        """Return ``buf`` (taken from :meth:`take`, no longer used by its taker)."""
        key = self._key(buf.shape, buf.dtype, buf.device)
        with self._lock:
            self._free.setdefault(key, []).append(buf)
            self._free.move_to_end(key)
            self._bytes += buf.capacity
            while self._bytes > self.cap and self._free:
                old, bufs = next(iter(self._free.items()))
                self._bytes -= bufs.pop(0).capacity
                if not bufs:
                    del self._free[old]


_POOL = _BufferPool(cap=512 << 20)
"""Saved sources of recorded launches and their adjoints' scratch."""

_REBINDS: dict = {}


def _rebinds(device):
    """The hooks' packed launches on ``device`` (``sim.launch``: packed once per call site,
    re-bound to each substep's arrays; a hook launches 1-3 small kernels a substep, whose
    ``wp.launch`` argument packing cost more than the kernels)."""
    from motionphysics.sim.launch import Rebinds

    wp = init_warp()
    dev = wp.get_device(device)
    rb = _REBINDS.get(dev.alias)
    if rb is None:
        rb = _REBINDS[dev.alias] = Rebinds(wp, dev)
    return rb


def _region_copy(src, dst, dim, src_base, dst_base, device) -> None:
    """``dst[t + dst_base] <- src[t + src_base]`` for t in the box ``dim``: a full grid's
    sub-box into a box-sized array (``src_base`` = the box's first node) or back."""
    from motionphysics.sim import kernels as K

    _rebinds(device).launch(
        K._copy_region_vec3,
        tuple(dim[:2]),  # (i, j) rows, each looping over k
        [src, src_base, dst_base, int(dim[2])],
        [dst],
    )


def _launch(
    kernel,
    dim,
    inputs: list,
    targets: list,
    extra_outputs: Sequence = (),
    device=None,
    grid_offset=None,
):
    """Launch ``kernel(*inputs, *sources, *targets, *extra_outputs)`` modifying ``targets`` in place.

    Without an active tape the sources ARE the targets (each thread reads and writes only
    its own element). With a tape, the sources are saved copies and a custom adjoint is
    recorded: on the launch domain ``targets.grad <- J^T targets.grad`` (elsewhere it is
    left as is), and the inputs' (parameters', positions') ``.grad`` accumulate.
    ``grid_offset``: for grid kernels launched over a sub-box (``dim``) of 3D targets,
    the box's first node (the kernel's first input); such kernels also take the offset of
    their source (``src_off``, appended here as their last input): 0 in place, the box's
    first node for a saved copy, which holds the launch domain only (the kernel and its
    adjoint read nothing else). The recorded adjoint may run once (its saved sources are
    then reused by later recordings).
    """
    wp = init_warp()
    tape = _active_tape()
    needs_grad = any(getattr(a, "requires_grad", False) for a in (*inputs, *targets))
    zero = wp.vec3i(0, 0, 0)
    if tape is None or not needs_grad:
        grid_inputs = [zero] if grid_offset is not None else []
        _rebinds(device).launch(
            kernel, dim, [*inputs, *grid_inputs, *targets], [*targets, *extra_outputs]
        )
        return
    saved = []
    for a in targets:
        if grid_offset is None:
            buf = _POOL.take(a.shape, a.dtype, a.device)
            copy_array(buf, a)
        else:
            buf = _POOL.take(dim, a.dtype, a.device)
            _region_copy(a, buf, dim, grid_offset, zero, device)
        saved.append(buf)
    inputs = [*inputs, grid_offset] if grid_offset is not None else list(inputs)
    _rebinds(device).launch(kernel, dim, [*inputs, *saved], [*targets, *extra_outputs])
    record = _LaunchAdjoint(
        tape, kernel, dim, inputs, targets, extra_outputs, device, grid_offset, saved
    )
    tracked = [a for a in (*inputs, *targets) if isinstance(a, wp.array) and a.grad is not None]
    tape.record_func(backward=record, arrays=tracked)


class _LaunchAdjoint:
    """The recorded adjoint of one :func:`_launch` under a tape (one object with slots
    rather than a closure: a rollout keeps thousands of these alive until its backward,
    and every object Python's garbage collector tracks costs collection time)."""

    __slots__ = (
        "tape",
        "kernel",
        "dim",
        "inputs",
        "targets",
        "extra_outputs",
        "device",
        "grid_offset",
        "saved",
        "done",
    )

    def __init__(
        self, tape, kernel, dim, inputs, targets, extra_outputs, device, grid_offset, saved
    ):
        self.tape = tape
        self.kernel = kernel
        self.dim = dim
        self.inputs = inputs
        self.targets = targets
        self.extra_outputs = extra_outputs
        self.device = device
        self.grid_offset = grid_offset
        self.saved = saved
        self.done = False

    def __call__(self) -> None:
        if self.done:
            raise RuntimeError(
                "a recorded boundary launch was back-propagated twice; record the step again"
            )
        self.done = True
        wp = init_warp()
        tape, dim, grid_offset = self.tape, self.dim, self.grid_offset
        inputs, targets, extra_outputs, saved = (
            self.inputs,
            self.targets,
            self.extra_outputs,
            self.saved,
        )
        # In place: each thread reads and writes only its own element, so the sources'
        # adjoint can be the targets' .grad itself (on the launch domain: a view with the
        # saved source's indexing). In the reverse pass a thread first reads the incoming
        # gradient of its element (the store adjoint, which zeroes it) and then adds
        # J^T of it into the same element (the source load's adjoint). No scratch, no copy.
        adj_saved = []
        adj_targets = []
        for a in targets:
            if a.grad is None:
                adj_saved.append(None)
                adj_targets.append(None)
                continue
            if grid_offset is None:
                adj_saved.append(a.grad)
            else:
                o = [int(grid_offset[i]) for i in range(3)]
                adj_saved.append(
                    a.grad[o[0] : o[0] + dim[0], o[1] : o[1] + dim[1], o[2] : o[2] + dim[2]]
                )
            adj_targets.append(a.grad)
        adj_inputs = [tape.get_adjoint(a) if isinstance(a, wp.array) else None for a in inputs]
        adj_extra = [tape.get_adjoint(a) for a in extra_outputs]
        _rebinds(self.device).launch(
            self.kernel,
            dim,
            [*inputs, *saved],
            [*targets, *extra_outputs],
            [*adj_inputs, *adj_saved],
            [*adj_targets, *adj_extra],
            adjoint=True,
        )
        for buf in saved:
            _POOL.give(buf)


@dataclass(frozen=True)
class _Window:
    start: float
    end: float
    unit: str

    def now(self, t: float, substep: int, dt: float) -> float:
        """The clock this window is measured in: seconds (shifted by round-off slack) or substeps."""
        if self.unit == "substeps":
            return float(substep)
        return float(t) + _TIME_EPS * float(dt)

    def active(self, t: float, substep: int, dt: float) -> bool:
        u = self.now(t, substep, dt)
        return self.start <= u < self.end


def _window(entry, where: str) -> _Window:
    # ``end`` null (an impulse delivered at ``start``; release_particles checks its own)
    # leaves the window open
    start = float(entry.start)
    end = _NO_END if entry.end is None else float(entry.end)
    if not (math.isfinite(start) and math.isfinite(end)):
        raise UserInputError(f"{where}: start and end must be finite numbers")
    if end <= start:
        raise UserInputError(f"{where}.end: expected end > start, got start={start:g}, end={end:g}")
    if entry.unit == "substeps":
        if start != round(start) or (end != round(end) and end != _NO_END):
            raise UserInputError(
                f"{where}: with unit 'substeps', start and end must be whole substep indices"
            )
        if start < 0:
            raise UserInputError(f"{where}.start: expected a substep index >= 0, got {start:g}")
    return _Window(start, end, entry.unit)


def _as_model(entry, union, where: str):
    """A config entry as its pydantic model (plain mappings are validated like the config)."""
    if not isinstance(entry, dict):
        return entry
    from pydantic import TypeAdapter, ValidationError

    try:
        return TypeAdapter(union).validate_python(entry)
    except ValidationError as err:
        e = err.errors()[0]
        loc = "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in e.get("loc", ())[1:])
        raise UserInputError(f"{where}{loc}: {e.get('msg', 'invalid value')}") from None


def _box(box, where: str) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(box[0], dtype=np.float64)
    hi = np.asarray(box[1], dtype=np.float64)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise UserInputError(f"{where}: box corners must be finite")
    if not np.all(lo < hi):
        raise UserInputError(
            f"{where}: expected [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max"
        )
    return lo, hi


def _unit(vec, where: str) -> np.ndarray:
    n = np.asarray(vec, dtype=np.float64)
    norm = float(np.linalg.norm(n))
    if not math.isfinite(norm) or norm < 1e-12:
        raise UserInputError(f"{where}: expected a nonzero direction vector, got {list(vec)}")
    return n / norm


def _t3(a) -> tuple[float, float, float]:
    return tuple(float(x) for x in np.asarray(a, dtype=np.float64).reshape(3))  # type: ignore[return-value]


def _finite(vec, where: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(vec, dtype=np.float64))
    if not np.all(np.isfinite(a)):
        raise UserInputError(f"{where}: expected finite numbers, got {vec}")
    return a


def _span(x0: np.ndarray) -> str:
    lo, hi = x0.min(axis=0), x0.max(axis=0)
    return "[" + ", ".join(f"{a:.3g}..{b:.3g}" for a, b in zip(lo, hi, strict=True)) + "]"


def _selection(entry, x0: np.ndarray, where: str) -> np.ndarray:
    """Boolean mask [P] of the particles an entry acts on (box, sphere, or all)."""
    if entry.box is not None:
        lo, hi = _box(entry.box, f"{where}.box")
        sel = np.all((x0 >= lo) & (x0 <= hi), axis=1)
        shape = "box"
    elif entry.sphere is not None:
        c = _finite(entry.sphere[0], f"{where}.sphere")
        r = float(entry.sphere[1])
        if not (math.isfinite(r) and r > 0):
            raise UserInputError(f"{where}.sphere: expected a radius > 0, got {r:g}")
        sel = np.sum((x0 - c) ** 2, axis=1) <= r * r
        shape = "sphere"
    else:
        return np.ones(x0.shape[0], dtype=bool)
    if not sel.any():
        raise UserInputError(
            f"{where}.{shape}: selects no particles (the particles span x,y,z {_span(x0)})"
        )
    return sel


# ------------------------------------------------------------------------ operations


DEFAULT_COLLIDER_FRICTION = 0.3
"""Coulomb coefficient of a frictional ``surface_collider`` that gives none."""


@dataclass
class _GridOp:
    where: str
    window: _Window
    kind: str  # clamp_grid | bounding_box | sticky | slip | frictional | cut
    scalars: dict[str, Any] = field(default_factory=dict)
    param: BoundaryParam | None = None


@dataclass
class _ParticleOp:
    where: str
    window: _Window
    kind: str  # accel | translation | rotation | release
    mask: Any = None  # wp.array float32 [P] (1 selected) -- or release_at for `release`
    scalars: dict[str, Any] = field(default_factory=dict)
    param: BoundaryParam | None = None
    last_release: float = 0.0


@dataclass
class _CutOp:
    where: str
    window: _Window
    use_box: int
    box_lo: tuple
    box_hi: tuple
    point: tuple
    normal: tuple


class BoundaryProgram:
    """The boundary conditions and forces of one simulation (see the module docstring).

    Attributes:
        params: learnable parameters (:class:`BoundaryParam`), in config order.
        selected: number of particles each force entry selects, by ``"forces[i]"``.
        has_cut: whether a ``cut`` collider exists (the State then needs ``active``).
        particle_count, device, domain_lo, dx, grid_dims: the geometry it was built for.
    """

    def __init__(
        self, *, particle_count: int, device: str, domain_lo, dx: float, grid_dims, walls=None
    ):
        self.particle_count = int(particle_count)
        self.device = device
        self.domain_lo = tuple(float(a) for a in domain_lo)
        self.dx = float(dx)
        self.grid_dims = tuple(int(n) for n in grid_dims)
        self.walls = None if walls is None else tuple(tuple(float(a) for a in w) for w in walls)
        """The material box ``(lo, hi)`` [m] whose faces are walls (Model.walls), or None
        (legacy: particles kept in :func:`particle_bounds`, walls by ``padding`` only)."""
        self._plane_ops: list[_GridOp] = []  # colliders whose particles are projected
        self._static_ops: list[_GridOp] = []  # the static scene (level set), projected too
        self.params: list[BoundaryParam] = []
        self.selected: dict[str, int] = {}
        self._grid_ops: list[_GridOp] = []
        self._particle_ops: list[_ParticleOp] = []
        self._cut_ops: list[_CutOp] = []
        if self.walls is None:
            self._x_min, self._x_max = particle_bounds(self.domain_lo, self.dx, self.grid_dims)
        else:
            self._x_min, self._x_max = self.walls

    # -------------------------------------------------------------- construction

    @classmethod
    def from_config(
        cls, boundary_conditions: Sequence, forces: Sequence, model, x0=None, static=None
    ) -> BoundaryProgram:
        """Build from config entries and a sim Model (CONTRACTS.md: Model fields used).

        ``x0``: initial particle positions [m], (P, 3) array / tensor / wp.array vec3;
        default ``model.particle_x0``.
        """
        if x0 is None:
            x0 = getattr(model, "particle_x0", None)
            if x0 is None:
                raise TypeError(
                    "BoundaryProgram.from_config needs x0= or model.particle_x0 (initial positions)"
                )
        return cls.build(
            boundary_conditions,
            forces,
            x0=x0,
            domain_lo=model.domain_lo,
            dx=model.dx,
            grid_dims=model.grid_dims,
            device=model.device,
            walls=getattr(model, "walls", None),
            static=static,
        )

    @classmethod
    def build(
        cls,
        boundary_conditions: Sequence,
        forces: Sequence,
        *,
        x0,
        domain_lo,
        dx: float,
        grid_dims,
        device: str = "cpu",
        walls=None,
        static=None,
    ) -> BoundaryProgram:
        """Build from config entries and explicit geometry.

        ``x0``: initial particle positions [m], (P, 3); ``domain_lo`` [m] (3,) position of
        node (0,0,0); ``dx`` [m]; ``grid_dims`` (nx, ny, nz) node counts; ``walls``: the
        material box ``(lo, hi)`` [m] (Model.walls) or None; ``static``: the static
        scene's :class:`~motionphysics.scene.region.StaticCollider` or None.
        Bad entries raise :class:`UserInputError` naming ``boundary_conditions[i]`` / ``forces[i]``.
        """
        if hasattr(x0, "detach"):
            x0 = x0.detach().cpu().numpy()
        elif hasattr(x0, "numpy") and not isinstance(x0, np.ndarray):
            x0 = x0.numpy()
        x0 = np.asarray(x0, dtype=np.float64).reshape(-1, 3)
        prog = cls(
            particle_count=x0.shape[0],
            device=device,
            domain_lo=domain_lo,
            dx=dx,
            grid_dims=grid_dims,
            walls=walls,
        )
        for i, bc in enumerate(boundary_conditions):
            where = f"boundary_conditions[{i}]"
            prog._add_bc(_as_model(bc, BoundaryCondition, where), where)
        for i, force in enumerate(forces):
            where = f"forces[{i}]"
            prog._add_force(_as_model(force, Force, where), x0, where)
        if prog.walls is not None and not any(op.kind == "bounding_box" for op in prog._grid_ops):
            prog._add_domain_walls()
        if static is not None:
            prog._add_static(static)
        return prog

    def _add_static(self, static) -> None:
        """The static scene as a collider at rest (a level set, ``StaticCollider``): its
        grid condition after the config's, its particle projection after the planes'."""
        wp = init_warp()
        if static.mode not in ("sticky", "slip", "frictional"):
            raise UserInputError(
                f"scene.static_collider: expected frictional, sticky or slip, got {static.mode!r}"
            )
        param = None
        if static.mode == "frictional":
            param = self._new_param("scene.static_friction", float(static.friction), "-")
        scalars = {
            "ls_lo": _t3(static.lo),
            "inv_h": 1.0 / float(static.h),
            "phi": wp.array(np.ascontiguousarray(static.phi), dtype=float, device=self.device),
            "nrm": wp.array(np.ascontiguousarray(static.normal), dtype=wp.vec3, device=self.device),
        }
        op = _GridOp(
            "scene.static_collider", _Window(0.0, math.inf, "seconds"), "static", scalars, param
        )
        op.scalars["mode"] = static.mode
        self._grid_ops.append(op)
        self._static_ops.append(op)

    def _add_domain_walls(self) -> None:
        """Slip walls on the faces of the material box when the config names no
        ``bounding_box``: the nodes on or beyond a face lose their outward velocity.

        G2P keeps particles inside the box by projecting their positions onto it; without
        a wall in the grid, the grid velocity there still pointed out of the box (gravity
        kept accelerating it), so a body that reached a face was pressed flat against it
        (a ball fallen onto the domain floor ended as a sheet of zero thickness). The faces
        are walls whatever the config says; ``bounding_box`` adds friction or thickness."""
        first, last = self._wall_nodes(2)
        self._grid_ops.append(
            _GridOp(
                "domain walls",
                _Window(0.0, math.inf, "seconds"),
                "bounding_box",
                {"first": first, "last": last},
                None,
            )
        )

    def _new_param(self, name: str, value, unit: str) -> BoundaryParam:
        wp = init_warp()
        v = np.asarray(value, dtype=np.float32).reshape(-1)
        if v.size == 3:
            arr = wp.array(v.reshape(1, 3), dtype=wp.vec3, device=self.device, requires_grad=True)
        else:
            arr = wp.array(v.reshape(1), dtype=float, device=self.device, requires_grad=True)
        p = BoundaryParam(name=name, array=arr, size=int(v.size), unit=unit)
        self.params.append(p)
        return p

    def _node_positions_1d(self, a: int) -> np.ndarray:
        return self.domain_lo[a] + self.dx * np.arange(self.grid_dims[a])

    def _add_bc(self, bc, where: str) -> None:
        win = _window(bc, where)
        if isinstance(bc, ClampGrid):
            lo, hi = _box(bc.box, f"{where}.box")
            tol = 1e-4 * self.dx
            if not all(
                np.any(
                    (self._node_positions_1d(a) >= lo[a] - tol)
                    & (self._node_positions_1d(a) <= hi[a] + tol)
                )
                for a in range(3)
            ):
                raise UserInputError(f"{where}.box: contains no grid node of the simulation domain")
            vel = _finite(bc.velocity, f"{where}.velocity")
            param = self._new_param(f"{where}.velocity", vel, "m/s")
            axis = tuple(1.0 if a else 0.0 for a in bc.axis)
            if not any(bc.axis):
                raise UserInputError(f"{where}.axis: expected at least one clamped axis (true)")
            self._grid_ops.append(
                _GridOp(
                    where,
                    win,
                    "clamp_grid",
                    {"box_lo": _t3(lo), "box_hi": _t3(hi), "axis": axis},
                    param,
                )
            )
        elif isinstance(bc, BoundingBox):
            if 2 * bc.padding >= min(self.grid_dims):
                raise UserInputError(
                    f"{where}.padding: {bc.padding} cells leaves no interior in a grid of {self.grid_dims} nodes"
                )
            param = self._new_param(f"{where}.friction", float(bc.friction), "-")
            first, last = self._wall_nodes(int(bc.padding))
            self._grid_ops.append(
                _GridOp(where, win, "bounding_box", {"first": first, "last": last}, param)
            )
        elif isinstance(bc, SurfaceCollider):
            point = _finite(bc.point, f"{where}.point")
            normal = _unit(bc.normal, f"{where}.normal")
            geo = {"point": _t3(point), "normal": _t3(normal)}
            if bc.mode == "cut":
                use_box = bc.box is not None
                lo, hi = _box(bc.box, f"{where}.box") if use_box else (np.zeros(3), np.zeros(3))
                param = self._new_param(f"{where}.damping", float(bc.damping), "-")
                self._grid_ops.append(
                    _GridOp(
                        where,
                        win,
                        "cut",
                        {**geo, "use_box": int(use_box), "box_lo": _t3(lo), "box_hi": _t3(hi)},
                        param,
                    )
                )
                self._cut_ops.append(
                    _CutOp(where, win, int(use_box), _t3(lo), _t3(hi), _t3(point), _t3(normal))
                )
                return
            if bc.box is not None:
                raise UserInputError(
                    f"{where}.box: only the 'cut' mode takes a box (mode is {bc.mode!r})"
                )
            if bc.mode == "sticky" and bc.friction not in (None, 0.0):
                raise UserInputError(f"{where}.friction: must be 0 (or absent) with mode 'sticky'")
            param = None
            if bc.mode == "frictional":
                friction = DEFAULT_COLLIDER_FRICTION if bc.friction is None else float(bc.friction)
                param = self._new_param(f"{where}.friction", friction, "-")
            op = _GridOp(where, win, bc.mode, geo, param)
            self._grid_ops.append(op)
            self._plane_ops.append(op)
        else:  # pragma: no cover - the config's discriminated union admits nothing else
            raise UserInputError(f"{where}.type: unknown boundary condition {type(bc).__name__}")

    def _wall_nodes(self, padding: int):
        """``(first, last)`` node indices per axis (wp.vec3i): ``bounding_box`` constrains the
        nodes ``i <= first`` and ``i >= last``. These are the ``padding`` outermost nodes of the
        grid and, with explicit :attr:`walls`, every node on or beyond a wall face (so the
        wall acts at the domain face, where G2P's projection also holds the particles)."""
        wp = init_warp()
        first = [padding - 1] * 3
        last = [n - padding for n in self.grid_dims]
        if self.walls is not None:
            tol = 1e-4
            for a in range(3):
                g_lo = (self.walls[0][a] - self.domain_lo[a]) / self.dx
                g_hi = (self.walls[1][a] - self.domain_lo[a]) / self.dx
                # nodes on or beyond the face, as a collider plane's (scene.prepare puts
                # the faces half-way between nodes: see prepare.WALL_PHASE)
                first[a] = max(first[a], int(math.floor(g_lo + tol)))
                last[a] = min(last[a], int(math.ceil(g_hi - tol)))
        return wp.vec3i(*first), wp.vec3i(*last)

    def _add_force(self, force, x0: np.ndarray, where: str) -> None:
        wp = init_warp()
        win = _window(force, where)
        sel = _selection(force, x0, where)
        self.selected[where] = int(sel.sum())
        mask = wp.array(sel.astype(np.float32), dtype=float, device=self.device)
        if isinstance(force, AddImpulse):
            # an impulse: the velocity change `force` [m/s], delivered evenly over the window
            # [start, end) when `end` is given, else within the one substep holding `start`
            param = self._new_param(f"{where}.force", _finite(force.force, f"{where}.force"), "m/s")
            given_end = force.end is not None
            self._particle_ops.append(
                _ParticleOp(where, win, "impulse", mask, {"given_end": given_end}, param)
            )
        elif isinstance(force, AddConstantForce):
            param = self._new_param(
                f"{where}.force", _finite(force.force, f"{where}.force"), "m/s^2"
            )
            self._particle_ops.append(_ParticleOp(where, win, "accel", mask, {}, param))
        elif isinstance(force, ForceParticlesTranslation):
            if not any(force.axis):
                raise UserInputError(f"{where}.axis: expected at least one imposed axis (true)")
            param = self._new_param(
                f"{where}.velocity", _finite(force.velocity, f"{where}.velocity"), "m/s"
            )
            axis = tuple(1.0 if a else 0.0 for a in force.axis)
            self._particle_ops.append(
                _ParticleOp(where, win, "translation", mask, {"axis": axis}, param)
            )
        elif isinstance(force, ForceParticlesRotation):
            center = _finite(force.center, f"{where}.center")
            axis = _unit(force.axis_direction, f"{where}.axis_direction")
            omega = _finite(force.angular_velocity, f"{where}.angular_velocity")
            param = self._new_param(f"{where}.angular_velocity", omega, "rad/s")
            self._particle_ops.append(
                _ParticleOp(
                    where, win, "rotation", mask, {"center": _t3(center), "axis": _t3(axis)}, param
                )
            )
        elif isinstance(force, ReleaseParticles):
            if force.end is None:
                raise UserInputError(
                    f"{where}.end: release_particles needs the time the last layer is released"
                )
            release_at = _release_times(
                x0, sel, force.layers, "xyz".index(force.release_axis), win.start, win.end
            )
            arr = wp.array(release_at.astype(np.float32), dtype=float, device=self.device)
            self._particle_ops.append(
                _ParticleOp(
                    where, win, "release", arr, {}, None, last_release=float(release_at[sel].max())
                )
            )
        else:  # pragma: no cover
            raise UserInputError(f"{where}.type: unknown force {type(force).__name__}")

    # ---------------------------------------------------------------- parameters

    def param(self, name: str) -> BoundaryParam:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(f"no boundary parameter {name!r}; have {[p.name for p in self.params]}")

    def set_param_values(self, values: dict[str, Any]) -> None:
        """Overwrite parameter values (floats, sequences, numpy arrays or torch tensors)."""
        for name, value in values.items():
            p = self.param(name)
            if hasattr(value, "detach"):
                value = value.detach().cpu().numpy()
            v = np.asarray(value, dtype=np.float32).reshape(-1)
            if v.size != p.size:
                raise ValueError(f"{name}: expected {p.size} value(s), got {v.size}")
            p.array.assign(v.reshape(1, 3) if p.size == 3 else v)

    def param_values(self) -> dict[str, np.ndarray]:
        return {p.name: p.value() for p in self.params}

    def param_grads(self) -> dict[str, np.ndarray]:
        """Gradients accumulated by ``tape.backward`` (float32 (size,) each)."""
        return {p.name: p.grad() for p in self.params}

    def zero_param_grads(self) -> None:
        for p in self.params:
            if p.array.grad is not None:
                p.array.grad.zero_()

    @property
    def has_cut(self) -> bool:
        return bool(self._cut_ops)

    @property
    def is_empty(self) -> bool:
        return not (self._grid_ops or self._particle_ops or self._cut_ops)

    @property
    def has_static(self) -> bool:
        """Whether the static scene of a ``scene.region`` run collides."""
        return bool(self._static_ops)

    # --------------------------------------------------------------------- hooks

    def apply_pre_p2g(self, model, state, t: float, substep: int, dt: float) -> None:
        """Set imposed and frozen particle velocities on the state P2G reads (in place, idempotent)."""
        from motionphysics.sim import boundary_kernels as K

        n = self.particle_count
        for op in self._particle_ops:
            if op.kind == "translation" and op.window.active(t, substep, dt):
                _launch(
                    K._set_translation_velocity,
                    n,
                    [op.mask, op.param.array, op.scalars["axis"]],
                    [state.v],
                    device=self.device,
                )
            elif op.kind == "rotation" and op.window.active(t, substep, dt):
                _launch(
                    K._set_rotation_velocity,
                    n,
                    [op.mask, op.scalars["center"], op.scalars["axis"], op.param.array, state.x],
                    [state.v],
                    device=self.device,
                )
            elif op.kind == "release":
                now = op.window.now(t, substep, dt)
                if now < op.last_release:
                    _launch(
                        K._zero_frozen_velocity, n, [op.mask, now], [state.v], device=self.device
                    )

    def apply_grid(self, model, grid_v, t: float, substep: int, dt: float, region=None) -> None:
        """Grid conditions on node velocities ``grid_v`` [m/s] (nx, ny, nz) vec3, in place.

        ``region``: optional ``(offset, shape)`` (3 ints each) of the sub-box of nodes to
        process (the nodes the particles' stencils touch; the rest is not read by G2P).
        Default: the whole grid.
        """
        from motionphysics.sim import boundary_kernels as K

        init_warp()
        if tuple(grid_v.shape) != self.grid_dims:
            raise ValueError(
                f"grid_v has shape {tuple(grid_v.shape)}, the program was built for {self.grid_dims}"
            )
        if region is None:
            off, dims = (0, 0, 0), self.grid_dims
        else:
            off, dims = (tuple(int(a) for a in r) for r in region)
            if any(
                o < 0 or n < 0 or o + n > g
                for o, n, g in zip(off, dims, self.grid_dims, strict=True)
            ):
                raise ValueError(f"region {region} is not inside the grid {self.grid_dims}")
            if min(dims) == 0:
                return
        lo, dx = self.domain_lo, self.dx
        for op in self._grid_ops:
            if not op.window.active(t, substep, dt):
                continue
            for box_off, box_dims in self._act_boxes(op, off, dims):
                self._launch_grid_op(K, op, grid_v, box_off, box_dims, lo, dx)

    def _launch_grid_op(self, K, op, grid_v, off, dims, lo, dx) -> None:
        """Launch grid op ``op``'s kernel over the sub-box (``off``, ``dims``) of ``grid_v``."""
        wp = init_warp()
        off_v = wp.vec3i(*off)
        kw = {"device": self.device, "grid_offset": off_v}
        s = op.scalars
        if op.kind == "clamp_grid":
            _launch(
                K._clamp_grid,
                dims,
                [off_v, lo, dx, s["box_lo"], s["box_hi"], op.param.array, s["axis"]],
                [grid_v],
                **kw,
            )
        elif op.kind == "bounding_box":
            friction = op.param.array if op.param is not None else self._zero_friction()
            _launch(
                K._bounding_box,
                dims,
                [off_v, s["first"], s["last"], friction],
                [grid_v],
                **kw,
            )
        elif op.kind == "static":
            mode = {
                "sticky": K.MODE_STICKY,
                "slip": K.MODE_SLIP,
                "frictional": K.MODE_FRICTIONAL,
            }[s["mode"]]
            friction = op.param.array if op.param is not None else self._zero_friction()
            _launch(
                K._static_grid,
                dims,
                [
                    off_v,
                    lo,
                    dx,
                    s["ls_lo"],
                    s["inv_h"],
                    s["phi"],
                    s["nrm"],
                    int(mode),
                    friction,
                ],
                [grid_v],
                **kw,
            )
        elif op.kind == "cut":
            _launch(
                K._cut_grid,
                dims,
                [
                    off_v,
                    lo,
                    dx,
                    s["use_box"],
                    s["box_lo"],
                    s["box_hi"],
                    s["point"],
                    s["normal"],
                    op.param.array,
                ],
                [grid_v],
                **kw,
            )
        else:
            mode = {
                "sticky": K.MODE_STICKY,
                "slip": K.MODE_SLIP,
                "frictional": K.MODE_FRICTIONAL,
            }[op.kind]
            friction = op.param.array if op.param is not None else self._zero_friction()
            _launch(
                K._surface_collider,
                dims,
                [off_v, lo, dx, s["point"], s["normal"], int(mode), friction],
                [grid_v],
                **kw,
            )

    def _act_boxes(
        self, op, off: tuple[int, ...], dims: tuple[int, ...]
    ) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
        """Disjoint sub-boxes ``(offset, dims)`` of the box (``off``, ``dims``) that hold
        every node grid op ``op`` may change; its kernel is launched on these alone (under
        a tape: saved copies and adjoints over them alone). Exact: the kernels are the
        identity, with the identity adjoint, on every node left out, and they act on each
        node by itself, so launching on disjoint pieces gives the same values.

        * ``bounding_box``: the wall layers (nodes ``i <= first`` or ``i >= last`` on some
          axis), split into disjoint slabs axis by axis: on a body resting on the floor
          a slab a node or two thick, where the whole box was launched before.
        * an axis-aligned collider plane (``sticky``/``slip``/``frictional``): the nodes
          on or behind it, with the margin of :meth:`_may_act` (2 % of a cell).
        * anything else: the whole box, unless :meth:`_may_act` rules it out.
        """
        if min(dims) <= 0 or not self._may_act(op, off, dims):
            return []
        lo_i = [int(o) for o in off]
        hi_i = [int(o) + int(n) for o, n in zip(off, dims, strict=True)]  # exclusive
        if op.kind == "bounding_box":
            first, last = op.scalars["first"], op.scalars["last"]
            boxes = []
            for a in range(3):
                low_end = min(hi_i[a], int(first[a]) + 1)
                if low_end > lo_i[a]:  # the low wall layers inside the box
                    b_hi = list(hi_i)
                    b_hi[a] = low_end
                    boxes.append((list(lo_i), b_hi))
                # (past the low slab: with walls overlapping, a node is launched once)
                high_start = max(lo_i[a], int(last[a]), low_end)
                if high_start < hi_i[a]:
                    b_lo = list(lo_i)
                    b_lo[a] = high_start
                    boxes.append((b_lo, list(hi_i)))
                # what is left lies strictly between the walls along axis a
                lo_i[a] = max(lo_i[a], int(first[a]) + 1)
                hi_i[a] = min(hi_i[a], int(last[a]))
                if lo_i[a] >= hi_i[a]:
                    break
            return [
                (tuple(b_lo), tuple(h - l for l, h in zip(b_lo, b_hi, strict=True)))
                for b_lo, b_hi in boxes
            ]
        if op.kind in ("sticky", "slip", "frictional"):
            n = op.scalars["normal"]
            axes = [a for a in range(3) if n[a] != 0.0]
            if len(axes) == 1:
                a = axes[0]
                # node i is on or behind the plane when (lo + i dx - p) * sign(n) <= tol dx
                g = (float(op.scalars["point"][a]) - self.domain_lo[a]) / self.dx
                if n[a] > 0.0:
                    hi_i[a] = min(hi_i[a], int(math.floor(g + 0.02)) + 1)
                else:
                    lo_i[a] = max(lo_i[a], int(math.ceil(g - 0.02)))
                if lo_i[a] >= hi_i[a]:
                    return []
                return [(tuple(lo_i), tuple(h - l for l, h in zip(lo_i, hi_i, strict=True)))]
        return [(tuple(off), tuple(dims))]

    def _may_act(self, op, off: tuple[int, ...], dims: tuple[int, ...]) -> bool:
        """False when grid op ``op`` is the identity on every node of the box (``off``,
        ``dims``), so its launch (and, under a tape, its saved copy and adjoint) is skipped:
        walls whose layers the box does not reach, a collider plane every node of the box is
        more than 2 % of a cell in front of (the kernel's contact tolerance is 1e-4 cells;
        the margin dwarfs float32 round-off of the node positions). Exact: those kernels
        write every such node unchanged and give it the identity adjoint."""
        if op.kind == "bounding_box":
            first, last = op.scalars["first"], op.scalars["last"]
            return any(off[a] <= first[a] or off[a] + dims[a] - 1 >= last[a] for a in range(3))
        if op.kind in ("sticky", "slip", "frictional"):
            n = np.asarray(op.scalars["normal"], dtype=np.float64)
            q = np.asarray(op.scalars["point"], dtype=np.float64)
            lo = np.asarray(self.domain_lo, dtype=np.float64)
            box_lo = lo + np.asarray(off, dtype=np.float64) * self.dx
            box_hi = lo + (np.asarray(off) + np.asarray(dims) - 1).astype(np.float64) * self.dx
            nearest = np.where(n >= 0.0, box_lo, box_hi)  # the box corner deepest along -n
            return float(np.dot(nearest - q, n)) <= 0.02 * self.dx
        return True

    def apply_post_g2p(self, model, state_in, state_out, t: float, substep: int, dt: float) -> None:
        """Forces, imposed motion, frozen and removed particles on ``state_out`` (in place).

        ``state_in`` is the state the substep started from (read only: x, active).
        """
        from motionphysics.sim import boundary_kernels as K

        n = self.particle_count
        xb = (self._x_min, self._x_max)
        for op in self._particle_ops:
            if op.kind == "release":
                now = op.window.now(t, substep, dt)
                if now < op.last_release:
                    _launch(
                        K._hold_frozen,
                        n,
                        [op.mask, now, state_in.x],
                        [state_out.x, state_out.v, state_out.C],
                        device=self.device,
                    )
                continue
            if op.kind == "impulse":
                frac = _impulse_fraction(op, t, substep, dt)
                if frac > 0.0:
                    _launch(
                        K._add_velocity_change,
                        n,
                        [op.mask, op.param.array, float(frac), float(dt), *xb],
                        [state_out.x, state_out.v],
                        device=self.device,
                    )
                continue
            if not op.window.active(t, substep, dt):
                continue
            if op.kind == "accel":
                _launch(
                    K._add_acceleration,
                    n,
                    [op.mask, op.param.array, float(dt), *xb],
                    [state_out.x, state_out.v],
                    device=self.device,
                )
            elif op.kind == "translation":
                _launch(
                    K._impose_translation,
                    n,
                    [op.mask, op.param.array, op.scalars["axis"], float(dt), *xb, state_in.x],
                    [state_out.x, state_out.v],
                    device=self.device,
                )
            elif op.kind == "rotation":
                _launch(
                    K._impose_rotation,
                    n,
                    [
                        op.mask,
                        op.scalars["center"],
                        op.scalars["axis"],
                        op.param.array,
                        float(dt),
                        *xb,
                        state_in.x,
                    ],
                    [state_out.x, state_out.v, state_out.C],
                    device=self.device,
                )
        if self._cut_ops:
            self._apply_cuts(state_in, state_out, t, substep, dt)
        # Last: particles behind a collider plane are projected onto it (the grid condition
        # alone lets material settle about half a cell into the plane).
        for op in self._plane_ops:
            if not op.window.active(t, substep, dt):
                continue
            s = op.scalars
            sticky = int(op.kind == "sticky")
            friction = op.param.array if op.param is not None else self._zero_friction()
            _launch(
                K._project_plane,
                n,
                [s["point"], s["normal"], sticky, friction],
                [state_out.x, state_out.v],
                device=self.device,
            )
        for op in self._static_ops:
            s = op.scalars
            friction = op.param.array if op.param is not None else self._zero_friction()
            _launch(
                K._project_levelset,
                n,
                [s["ls_lo"], s["inv_h"], s["phi"], s["nrm"], int(s["mode"] == "sticky"), friction],
                [state_out.x, state_out.v],
                device=self.device,
            )

    def _apply_cuts(self, state_in, state_out, t, substep, dt) -> None:
        from motionphysics.sim import boundary_kernels as K

        wp = init_warp()
        act_in = getattr(state_in, "active", None)
        act_out = getattr(state_out, "active", None)
        if act_in is None or act_out is None:
            raise RuntimeError(
                "a 'cut' collider needs State.active (float32 [P]); see CONTRACTS.md, sim"
            )
        # The first cut starts from state_in's mask; the mask is never differentiated.
        wp.copy(act_out, act_in)
        for op in self._cut_ops:
            mark = int(op.window.active(t, substep, dt))
            _launch(
                K._cut_particles,
                self.particle_count,
                [mark, op.use_box, op.box_lo, op.box_hi, op.point, op.normal, state_in.x],
                [state_out.x, state_out.v, state_out.C, act_out],
                device=self.device,
            )

    def _zero_friction(self):
        if not hasattr(self, "_zero_friction_arr"):
            wp = init_warp()
            self._zero_friction_arr = wp.zeros(1, dtype=float, device=self.device)
        return self._zero_friction_arr


def _impulse_fraction(op, t: float, substep: int, dt: float) -> float:
    """Fraction of an ``add_impulse``'s velocity change delivered in this substep: 1 in the
    substep holding ``start`` when no ``end`` was given, else ``dt / (end - start)`` (one
    substep's share; ``1 / (end - start)`` with ``unit: substeps``) inside the window."""
    w = op.window
    if not op.scalars["given_end"]:
        if w.unit == "substeps":
            return 1.0 if substep == int(w.start) else 0.0
        slack = _TIME_EPS * float(dt)  # a start on a substep edge belongs to the later one
        return 1.0 if t - slack <= w.start < t + dt - slack else 0.0
    if not w.active(t, substep, dt):
        return 0.0
    if w.unit == "substeps":
        return 1.0 / (w.end - w.start)
    return dt / (w.end - w.start)


def _release_times(
    x0: np.ndarray, sel: np.ndarray, layers: int, axis: int, start: float, end: float
) -> np.ndarray:
    """Release time per particle (float64 [P]): selected particles are cut into ``layers``
    equal-width slabs along ``axis``; the highest slab is released first, at
    ``start + (end - start) / layers``, the lowest at ``end``. Unselected: -inf (never frozen)."""
    out = np.full(x0.shape[0], -np.inf)
    c = x0[sel, axis]
    cmax, cmin = float(c.max()), float(c.min())
    width = (cmax - cmin) / layers
    if width > 0:
        layer = np.minimum(np.floor((cmax - c) / width), layers - 1)
    else:
        layer = np.zeros_like(c)
    out[sel] = start + (layer + 1.0) * (end - start) / layers
    return out
