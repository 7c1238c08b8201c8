"""MLS-MPM solver: ``Solver.step(state_in, state_out, dt)`` and time-step selection.

The solver validates and launches the kernels of :mod:`.kernels` (one code path for
``cpu`` and ``cuda``), owns the grid scratch, and calls the boundary hooks of
``model.boundary`` (CONTRACTS.md) each substep:
``apply_pre_p2g(model, state_in, ...)`` → P2G → grid update → ``apply_grid(model,
grid_v, ...)`` → G2P → ``apply_post_g2p(model, state_in, state_out, ...)``.

Every launch is recorded on an active ``wp.Tape``, so a step is differentiable with
respect to ``state_in`` and the model's parameter arrays. A tape needs the grid
arrays of each recorded substep intact until its backward pass: pass ``grid=`` (one
:class:`Grid` per recorded substep, what :mod:`.rollout` does). The transfers P2G and
G2P record hand-written adjoint kernels (``kernels._p2g_adjoint`` / ``_g2p_adjoint``,
checked against finite differences in tests/sim/test_kernels.py) because Warp's
generated adjoints of the 27-node stencil loops cost 2-6x their forward. The elastic
(fixed corotated) stress runs ``kernels._stress_elastic`` (Newton polar rotation, 3-4x
faster than the SVD) and, under a tape, stores the rotations for the SVD-free
``_stress_elastic_adjoint``; the other classes' stress kernels use Warp's generated adjoint
(SVD included). A one-object, all-elastic scene runs the stress and P2G as one kernel
(``kernels._stress_elastic_p2g``), recorded or not: recorded, it also stores the affine
matrices and rotations, and the two hand-written adjoints are recorded as for the two
kernels. A recorded substep keeps its adjoints' data in plain records (:class:`_Call`),
not closures: they stay alive until the backward, and Python's garbage collector walks
every object they hold.

On CPU, Warp runs a launch on one thread; with ``SolverConfig.threads = 2`` the
particles are split in two chunks, the first launched from the caller's thread and the
second from a worker thread (ctypes releases the GIL), each scattering into a PRIVATE
grid, summed by the grid update. Grid kernels on CPU run over the particles' bounding
box only (the active region), and so do the grid hooks, the saved copies a recorded
hook keeps (``boundary._launch``) and the zeroing of the grid adjoints."""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from motionphysics.runtime import init_warp
from motionphysics.sim import kernels as _k
from motionphysics.sim.launch import Rebinds
from motionphysics.sim.model import Model
from motionphysics.sim.state import State, copy_array

DEFAULT_CFL = 0.4


def _active_tape():
    import warp._src.context as ctx  # the tape Warp is recording on, if any

    return ctx.runtime.tape


class _Call(tuple):
    """``(fn, *args)``, recorded on a tape as the backward ``fn(*args)``.

    A recorded substep keeps its adjoints' data in a few of these instead of closures: a
    closure and its cells, argument lists and nested functions were ~85 objects per
    substep that Python's cyclic garbage collector tracks, and a 16-frame, 231-substep
    recording (~300,000 of them, all alive until the backward) cost ~0.3-0.45 ms per
    substep in collections, a third of the recorded forward at 1,500 particles."""

    __slots__ = ()

    def __call__(self) -> None:
        self[0](*self[1:])


class _Replays:
    """CPU kernel launches packed once and replayed by a direct call of the kernel's entry
    point: ``wp.launch`` packs every argument into ctypes on every call (~30 us for the
    fused stress + P2G kernel's 23 arguments), a replay costs ~2 us. A substep makes 6
    launches, the two chunked ones on two threads that contend for the GIL while packing.

    A launch is keyed by its kernel, its dimension, the identity of its arrays and the
    value of its other arguments; a hit also checks that each array is still the one it
    was packed from (weak references: an id reused by a new array after the old one died
    misses). Only for launches that nothing records (no tape, or ``record_tape=False``):
    the caller decides. Falls back to ``wp.launch`` off the CPU or in Warp's debug or
    floating-point-verification modes. The same kernel, inputs and outputs: bitwise the
    same results."""

    MAX = 64

    def __init__(self, wp, device, enabled: bool = True) -> None:
        import weakref

        self.wp = wp
        self.device = device
        self._weakref = weakref.ref
        self._entries: dict = {}
        self._array = wp.array
        from warp._src import context as ctx

        self._capture = ctx._get_apic_capture_for_device
        cfg = wp.config
        self.enabled = enabled and device.is_cpu and cfg.mode != "debug" and not cfg.verify_fp

    def launch(self, kernel, dim, inputs: list, outputs: list) -> None:
        wp = self.wp
        if not self.enabled:
            wp.launch(
                kernel,
                dim=dim,
                inputs=inputs,
                outputs=outputs,
                device=self.device,
                record_tape=False,
            )
            return
        if self._capture(self.device) is not None:  # a CPU graph capture records launches
            wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)
            return
        array = self._array
        key = [kernel, dim]
        for a in (*inputs, *outputs):
            t = type(a)
            if t is array:
                key.append(id(a))
            elif hasattr(t, "_length_"):  # a Warp vector or matrix (a ctypes array)
                key.append(bytes(a))  # by value (a C-level copy, not 3-9 getitems)
            else:  # a scalar
                key.append(a)
        key = tuple(key)
        entry = self._entries.get(key)
        if entry is not None:
            refs, call = entry
            for r in refs:
                if r() is None:
                    entry = None
                    break
        if entry is None:
            entry = self._pack(key, kernel, dim, inputs, outputs)
        entry[1]()

    def _pack(self, key, kernel, dim, inputs, outputs):
        import ctypes
        import functools

        from warp._src import context as ctx

        wp = self.wp
        cmd = wp.launch(
            kernel,
            dim=dim,
            inputs=inputs,
            outputs=outputs,
            device=self.device,
            record_cmd=True,
        )
        args, _ = ctx._build_cpu_args_structs(kernel, cmd.hooks, cmd.params, False)
        bounds = cmd.bounds
        call = functools.partial(cmd.hooks.forward, ctypes.byref(bounds), ctypes.byref(args))
        call.keep = (bounds, args, cmd.module_exec)  # the packed structs, the loaded module
        refs = tuple(self._weakref(a) for a in (*inputs, *outputs) if type(a) is self._array)
        if len(self._entries) >= self.MAX:
            del self._entries[next(iter(self._entries))]
        entry = self._entries[key] = (refs, call)
        return entry


@dataclass(frozen=True)
class SolverConfig:
    """Options of :class:`Solver`."""

    threads: int | None = None
    """CPU only: particle chunks run on this many threads (1 or 2; None: 2 when the
    machine has 2+ cores and there are at least ``min_particles_per_thread`` per chunk)."""
    min_particles_per_thread: int = 2048
    """Below this many particles per chunk, threading costs more than it saves."""
    active_region: bool = True
    """CPU only: zero and update only the grid nodes around the particles' bounding box."""
    fuse_elastic_p2g: bool = True
    """Substeps of a one-object, all-elastic scene run the stress and P2G as one kernel
    (``kernels._stress_elastic_p2g``, same results); recorded ones too (it then also stores
    the affine matrices and rotations, and records the two kernels' hand-written
    adjoints). False: two launches (for comparisons)."""
    replay_launches: bool = True
    """CPU, untaped substeps: the kernel launches are packed once and replayed
    (:class:`_Replays`, same kernels and arguments). False: ``wp.launch`` every time (for
    comparisons)."""


@dataclass
class Grid:
    """Grid scratch of one substep.

    Attributes:
        velocity: node velocity after the grid update [m/s], shape (nx, ny, nz), dtype
            vec3 (full grid; what ``BoundaryProgram.apply_grid`` edits). Only nodes of the
            active region are written in a substep; G2P reads only those.
        mv: node momentum [kg m/s] (xyz) and mass [kg] (w) of the active region, shape
            (chunks, rx, ry, rz), dtype vec4, one private grid per particle chunk (summed
            by the grid update); set by :meth:`Solver.step`, None before the first step.
        offset: grid index of ``mv[:, 0, 0, 0]``, (3,) ints.
    """

    velocity: Any
    """(several objects: the objects' fields stacked along the first axis, shape
    (num_objects * nx, ny, nz), object o's node i at row i + o * nx; see :attr:`fields`)"""
    mv: Any = None
    offset: tuple[int, int, int] = (0, 0, 0)
    requires_grad: bool = False
    rotation: Any = None
    """Recorded substeps only: polar rotation of each elastic particle's trial F (P,) mat33,
    kept for the stress adjoint."""
    affine: Any = None
    """Recorded substeps only: the substep's affine matrices (P,) mat33 (see Solver.step)."""
    v_g2p: Any = None
    """Recorded substeps only: the particle velocities G2P gathered [m/s] (P,) vec3, before
    the post-G2P hooks edit ``state_out.v``; read by G2P's adjoint instead of re-gathering."""
    num_objects: int = 1
    clean: tuple | None = None
    """Recorded substeps: ``(offset, shape)`` of a box of nodes on which ``velocity.grad`` is
    known to be zero (None: nothing known). A recorded step zeroes the adjoint on its
    region unless the region lies in this box; G2P's adjoint (which scatters into it)
    clears it, and the grid update's adjoint, which consumes (zeroes) the whole region
    last in the substep's backward, sets it to the region."""

    def clean_on(self, offset, shape) -> bool:
        """Whether ``velocity.grad`` is known to be zero on the box (``offset``, ``shape``)."""
        box = self.clean
        if box is None:
            return False
        o, n = box
        return all(o[a] <= offset[a] and offset[a] + shape[a] <= o[a] + n[a] for a in range(3))

    @property
    def fields(self) -> list:
        """One (nx, ny, nz) node-velocity array per object (views of :attr:`velocity`)."""
        if self.num_objects == 1:
            return [self.velocity]
        nx = self.velocity.shape[0] // self.num_objects
        return [self.velocity[o * nx : (o + 1) * nx] for o in range(self.num_objects)]

    def zero_grad(self) -> None:
        """Zero the adjoints. ``velocity.grad`` is only ever written on the active region of
        the last recorded substep (G2P's adjoint scatters to the particles' stencils, the
        grid hooks and the grid update work on the region), so only that box is zeroed."""
        g = self.velocity.grad
        self.clean = None
        if g is not None:
            if self.mv is None or self.num_objects > 1:
                g.zero_()
            else:
                wp = init_warp()
                wp.launch(
                    _k._zero_region_vec3,
                    dim=tuple(self.mv.shape[1:3]),  # (i, j) rows, each looping over k
                    inputs=[wp.vec3i(*self.offset), int(self.mv.shape[3])],
                    outputs=[g],
                    device=g.device,
                    record_tape=False,
                )
        for a in (self.mv, self.affine):
            if a is not None and a.grad is not None:
                a.grad.zero_()

    def nbytes(self) -> int:
        n = self.velocity.capacity
        if self.mv is not None:
            n += self.mv.capacity
        n *= 2 if self.requires_grad else 1
        if self.affine is not None:
            n += self.affine.capacity * (2 if self.affine.requires_grad else 1)
        for a in (self.rotation, self.v_g2p):
            if a is not None:
                n += a.capacity
        return n


class Solver:
    """Explicit MLS-MPM integrator over a :class:`Model`."""

    def __init__(self, model: Model, config: SolverConfig | None = None):
        self.wp = init_warp()
        self.model = model
        self.config = config or SolverConfig()
        self.device = self.wp.get_device(model.device)
        threads = self.config.threads
        if threads is None:
            threads = 2 if (os.cpu_count() or 1) >= 2 else 1
            if model.particle_count < 2 * self.config.min_particles_per_thread:
                threads = 1
        self.num_objects = int(getattr(model, "num_objects", 1))
        # several objects: one chunk (each object scatters into its own region grid)
        self.chunks = 1 if not self.device.is_cpu else max(1, min(2, int(threads)))
        if self.num_objects > 1:
            self.chunks = 1
        oid = getattr(model, "object_id", None)
        if oid is None:
            oid = self.wp.zeros(model.particle_count, dtype=self.wp.int32, device=model.device)
        self._object_id = oid
        p = model.particle_count
        half = (p + 1) // 2
        self._ranges = [(0, p)] if self.chunks == 1 else [(0, half), (half, p - half)]
        self._pool = ThreadPoolExecutor(max_workers=1) if self.chunks > 1 else None
        self.grid = self.make_grid()
        wp = self.wp
        dims = model.grid_dims
        lo = np.asarray(model.domain_lo, dtype=np.float64)
        self._lo = wp.vec3(*lo)
        self._dims = wp.vec3i(*dims)
        # G2P projects particles onto the material box (the domain walls, Model.wall_box)
        wall_lo, wall_hi = model.wall_box
        self._x_min = wp.vec3(*wall_lo)
        self._x_max = wp.vec3(*wall_hi)
        self._gravity = wp.vec3(*model.gravity)
        self._bounds = wp.zeros(2, dtype=wp.vec3, device=model.device)
        self._R_dummy = None  # R output of the elastic stress when nothing records it
        self._private: list = []  # the chunks' region-sized G2P adjoint buffers
        self.affine = None  # affine matrices of untaped substeps (see _affine)
        self._rollout_buffers: dict | None = None  # the rollouts' tape buffers (Rollout._context)
        # the packed launches of untaped substeps
        self._replays = _Replays(wp, self.device, self.config.replay_launches)
        # recorded substeps and their adjoints: packed once per call site, re-bound to each
        # substep's own arrays (sim.launch)
        self._rebinds = Rebinds(wp, self.device, self.config.replay_launches)
        self.classes = tuple(int(c) for c in np.unique(model.material_class.numpy()))
        """Material class ids present (one stress kernel launch each)."""

    def make_grid(self, requires_grad: bool = False) -> Grid:
        """Fresh grid scratch; pass one per recorded substep to :meth:`step` under a tape.

        Without gradients the node velocities are zeroed. With them (a recorded substep)
        the velocity array and its adjoint are left uninitialised on CPU: a substep writes
        and reads only its active region (the step zeroes the adjoint's region itself), so
        the pages outside it are never touched and cost no memory; zeroed full grids were
        6.6 MB per recorded substep at 64^3 (2/3 of the tape), and their estimate held the
        tapes a forward keeps to ~30 of 48 frames at 20k particles."""
        wp = self.wp
        nx, ny, nz = self.model.grid_dims
        shape = (nx * self.num_objects, ny, nz)
        dev = self.model.device
        if requires_grad and self.device.is_cpu and self.num_objects == 1:
            v = wp.empty(shape, dtype=wp.vec3, device=dev)
            v.grad = wp.empty(shape, dtype=wp.vec3, device=dev)
        else:
            v = wp.zeros(shape, dtype=wp.vec3, device=dev, requires_grad=requires_grad)
        return Grid(velocity=v, requires_grad=requires_grad, num_objects=self.num_objects)

    def _region(self, state: State) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """(offset, shape) of the grid nodes the particles' stencils touch (+1 node margin)."""
        dims = np.asarray(self.model.grid_dims)
        if not (self.device.is_cpu and self.config.active_region):
            return (0, 0, 0), tuple(int(d) for d in dims)
        args = ([state.x, state.particle_count], [self._bounds])
        if _active_tape() is None:
            self._replays.launch(_k._bounds, 1, *args)
        else:
            self._launch_untaped(_k._bounds, 1, *args)
        b = self._bounds.numpy().astype(np.float64)
        g = (b - np.asarray(self.model.domain_lo)) / self.model.dx
        if not np.all(np.isfinite(g)):
            return (0, 0, 0), tuple(int(d) for d in dims)
        # the kernels' stencil base is clamp(floor(g - 0.5), 0, n - 3); +-1 node for round-off
        lo = np.clip(np.floor(g[0] - 0.5), 0, dims - 3).astype(np.int64) - 1
        hi = np.clip(np.floor(g[1] - 0.5), 0, dims - 3).astype(np.int64) + 3
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, dims - 1)
        return tuple(int(a) for a in lo), tuple(int(a) for a in (hi - lo + 1))

    def _chunked(self, fn) -> None:
        if self._pool is None:
            fn(0, *self._ranges[0])
            return
        # the caller's thread runs the first chunk itself: one hand-off per launch, not two
        futures = [self._pool.submit(fn, c, *r) for c, r in enumerate(self._ranges) if c > 0]
        try:
            fn(0, *self._ranges[0])
        finally:
            for f in futures:
                f.result()

    def _launch_chunks(
        self, kernel, make_inputs, outputs: list, shared: tuple[int, ...] = ()
    ) -> None:
        """Launch ``kernel`` over the particle chunks (threads on CPU), tape-aware.

        ``make_inputs(chunk, start)`` gives the inputs of a chunk. Without a tape, or with
        one chunk, plain launches (recorded by Warp itself). With a tape and two chunks the
        launches are not recorded one by one: a custom backward runs both chunks' adjoint
        launches on the threads too, giving each chunk a PRIVATE adjoint buffer for the
        inputs listed in ``shared`` (indices of arrays both chunks read, e.g. the grid: their
        adjoints are scattered with Warp's CPU atomics, which are plain read-modify-writes)
        and summing those afterwards.
        """
        wp = self.wp
        dev = self.model.device
        tape = _active_tape()
        if tape is None or self._pool is None:
            self._chunked(
                lambda c, start, n: wp.launch(
                    kernel, dim=n, inputs=make_inputs(c, start), outputs=outputs, device=dev
                )
            )
            return
        self._chunked(
            lambda c, start, n: self._rebinds.launch(kernel, n, make_inputs(c, start), outputs)
        )
        per_chunk = [make_inputs(c, start) for c, (start, _n) in enumerate(self._ranges)]
        arrays = [
            a
            for a in (*[a for ins in per_chunk for a in ins], *outputs)
            if isinstance(a, wp.array) and a.grad is not None
        ]
        tape.record_func(
            backward=_Call(
                (Solver._chunks_backward, self, tape, kernel, per_chunk, outputs, shared)
            ),
            arrays=list({id(a): a for a in arrays}.values()),
        )

    def _chunks_backward(self, tape, kernel, per_chunk, outputs: list, shared) -> None:
        """The adjoint of :meth:`_launch_chunks`' two recorded chunk launches."""
        wp = self.wp
        private: dict[tuple[int, int], Any] = {}

        def adj(c: int, start: int, n: int) -> None:
            ins = per_chunk[c]
            adj_in = []
            for i, a in enumerate(ins):
                g = tape.get_adjoint(a)
                if i in shared and g is not None:
                    g = wp.zeros_like(g)
                    private[(c, i)] = g
                adj_in.append(g)
            adj_out = [tape.get_adjoint(o) for o in outputs]
            self._rebinds.launch(kernel, n, ins, outputs, adj_in, adj_out, adjoint=True)

        self._chunked(adj)
        for (_c, i), g in private.items():
            total = per_chunk[0][i].grad
            self._rebinds.launch(_k._add_vec3_3d, total.shape, [g], [total])

    def _record_grid_update_adjoint(self, grid: Grid, mv, shape, wp_off) -> None:
        """Record ``kernels._grid_update_adjoint`` for the grid update just launched."""
        _active_tape().record_func(
            backward=_Call((Solver._grid_update_backward, self, grid, mv, shape, wp_off)),
            arrays=[mv, grid.velocity],
        )

    def _grid_update_backward(self, grid: Grid, mv, shape, wp_off) -> None:
        self._rebinds.launch(
            _k._grid_update_adjoint,
            tuple(shape[:2]),  # (i, j) rows, each looping over k
            [mv, self.chunks, wp_off, grid.velocity.grad],
            [mv.grad],
        )
        # it consumed (zeroed) the node velocity adjoint on the region, the last in the
        # substep's backward to touch it
        grid.clean = (tuple(int(wp_off[a]) for a in range(3)), tuple(shape))

    def _region_grid(self, grid: Grid, shape: tuple[int, int, int], zero_grad: bool = True):
        """A zeroed (chunks, *shape) vec4 array for ``grid`` (reused when the shape allows);
        its adjoint zeroed too unless ``zero_grad`` is False."""
        wp = self.wp
        full = (self.chunks * self.num_objects, *shape)
        mv = grid.mv
        if mv is None or tuple(mv.shape) != full or mv.requires_grad != grid.requires_grad:
            # (under a tape every recorded substep has its own Grid, so its own array)
            mv = wp.zeros(
                full, dtype=wp.vec4, device=self.model.device, requires_grad=grid.requires_grad
            )
        else:
            mv.zero_()
            if zero_grad and mv.grad is not None:
                mv.grad.zero_()
        return mv

    def _stress_args(self, state_in: State, dt: float, start: int) -> list:
        """Inputs of the stress kernels (``kernels.STRESS_KERNELS``) for the chunk at ``start``."""
        m = self.model
        pr = m.params
        return [
            state_in.C,
            state_in.F,
            state_in.ep,
            state_in.active,
            m.volume,
            pr["density"],
            m.material_class,
            pr["E"],
            pr["nu"],
            pr["tau_Y"],
            pr["eta"],
            pr["theta_fric"],
            pr["mu"],
            pr["kappa"],
            pr["n"],
            m.dx,
            dt,
            start,
        ]

    def _p2g_args(self, state_in: State, affine, wp_off, chunk: int, start: int) -> list:
        """Inputs of ``kernels._p2g`` for chunk ``chunk`` (first particle ``start``)."""
        m = self.model
        return [
            state_in.x,
            state_in.v,
            affine,
            state_in.active,
            m.volume,
            m.params["density"],
            self._lo,
            m.dx,
            self._dims,
            start,
            chunk,
            wp_off,
            self._object_id,
            self.chunks if self.num_objects > 1 else 0,
        ]

    def step(
        self,
        state_in: State,
        state_out: State,
        dt: float,
        t: float = 0.0,
        substep: int = 0,
        grid: Grid | None = None,
    ) -> None:
        """Advance ``state_in`` by ``dt`` [s] into ``state_out`` (distinct states).

        ``t`` [s] (time at the start of the substep) and ``substep`` (global index) are
        passed to the boundary hooks. ``state_in`` may be modified in place by
        ``apply_pre_p2g`` (imposed / frozen velocities). Under a ``wp.Tape``, pass a
        ``grid`` made with ``make_grid(requires_grad=True)`` per recorded substep (a grid
        used again needs its adjoints at zero: a complete backward leaves them so, else call
        ``grid.zero_grad()``).
        """
        wp = self.wp
        m = self.model
        if state_in is state_out:
            raise ValueError("Solver.step needs distinct state_in and state_out (ping-pong)")
        grid = grid or self.grid
        dt = float(dt)
        if m.boundary is not None:
            m.boundary.apply_pre_p2g(m, state_in, t, substep, dt)
        off, shape = self._region(state_in)
        wp_off = wp.vec3i(*off)
        # under a tape, one object: the grid update records its hand-written adjoint, which
        # assigns the whole region's momentum adjoint (so it is not zeroed here)
        hand_grid = self.num_objects == 1 and grid.requires_grad and _active_tape() is not None
        grid.mv = mv = self._region_grid(grid, shape, zero_grad=not hand_grid)
        if hand_grid:
            # G2P's adjoint accumulates into the node velocity adjoint on this region only.
            # A complete backward of a substep leaves its region zero (Grid.clean), so a grid
            # recorded again on the same region (the next iteration) is not zeroed again.
            custom = self._g2p_custom(state_in, grid, state_out)
            if not (custom and grid.clean_on(off, shape)):
                self._rebinds.launch(
                    _k._zero_region_vec3,
                    tuple(shape[:2]),  # (i, j) rows, each looping over k
                    [wp_off, int(shape[2])],
                    [grid.velocity.grad],
                )
                # (Warp's own G2P adjoint would not clear it: nothing is known then)
                grid.clean = (off, shape) if custom else None
        grid.offset = off
        pr = m.params

        affine = self._affine(grid, state_out.F.requires_grad)

        def stress_inputs(chunk: int, start: int) -> list:
            return self._stress_args(state_in, dt, start)

        tape = _active_tape()
        fused = (
            self.config.fuse_elastic_p2g
            and self.classes == (_k.ELASTIC_CLASS,)
            and self.num_objects == 1
        )
        if fused and tape is not None:
            # recorded: with the hand-written P2G adjoint only (every adjoint buffer present)
            needed = [state_in.x, state_in.v, affine, pr["density"], mv]
            fused = all(a.grad is not None for a in needed)
        if fused:
            # all elastic, one object: stress and P2G fused in one pass; under a tape it
            # also stores the affine matrices and rotations the two adjoints read
            if tape is None:
                if self._R_dummy is None:
                    self._R_dummy = wp.empty(1, dtype=wp.mat33, device=m.device)
                R, store = self._R_dummy, 0
            else:
                R, store = self._rotation(grid), 1
            # untaped: packed launches replayed (each recorded substep has its own arrays)
            launch = self._replays.launch if tape is None else self._launch_untaped
            self._chunked(
                lambda c, start, n: launch(
                    _k._stress_elastic_p2g,
                    n,
                    [
                        state_in.x,
                        state_in.v,
                        state_in.C,
                        state_in.F,
                        state_in.ep,
                        state_in.active,
                        m.volume,
                        pr["density"],
                        pr["E"],
                        pr["nu"],
                        self._lo,
                        m.dx,
                        dt,
                        self._dims,
                        start,
                        c,
                        wp_off,
                        store,
                    ],
                    [state_out.F, state_out.ep, mv, affine, R],
                )
            )
            if tape is not None:
                # recorded in the order of the two launches it replaces
                self._record_elastic_stress(tape, state_in, state_out, affine, R, dt)
                self._record_p2g(tape, state_in, affine, mv, wp_off)
        # chunks write disjoint particles and their own private grid: no shared adjoints
        for cid in () if fused else self.classes:
            if cid == _k.ELASTIC_CLASS:
                self._elastic_stress(state_in, state_out, affine, grid, dt)
                continue
            self._launch_chunks(
                _k.STRESS_KERNELS[cid], stress_inputs, [state_out.F, state_out.ep, affine]
            )
        if not fused:
            self._p2g(state_in, affine, mv, wp_off)
        if self.num_objects == 1:
            args = ([mv, self.chunks, self._gravity, dt, wp_off], [grid.velocity])
            if tape is None:
                # (the same per-node expressions, launched over the (i, j) rows)
                self._replays.launch(_k._grid_update_rows, shape[:2], *args)
            elif hand_grid:  # its adjoint is recorded by hand just below
                if self.device.is_cpu:  # by rows, as untaped
                    self._rebinds.launch(_k._grid_update_rows, shape[:2], *args)
                else:  # a thread per node
                    self._rebinds.launch(_k._grid_update, shape, *args)
            else:
                wp.launch(
                    _k._grid_update,
                    dim=shape,
                    inputs=args[0],
                    outputs=args[1],
                    device=m.device,
                )
            if hand_grid:
                self._record_grid_update_adjoint(grid, mv, shape, wp_off)
        else:
            # one field per object, contact between them (kernels._make_contact_update)
            wp.launch(
                _k.contact_update_kernel(self.num_objects),
                dim=shape,
                inputs=[
                    mv,
                    self._gravity,
                    dt,
                    wp_off,
                    int(m.grid_dims[0]),
                    float(getattr(m, "contact_friction", 0.0)),
                ],
                outputs=[grid.velocity],
                device=m.device,
            )
        if m.boundary is not None:
            # only the active region is read by G2P: the hooks process just those nodes
            for field_v in grid.fields:
                m.boundary.apply_grid(m, field_v, t, substep, dt, region=(off, shape))

        self._g2p(state_in, grid, state_out, dt)
        if m.boundary is not None:
            m.boundary.apply_post_g2p(m, state_in, state_out, t, substep, dt)

    def _affine(self, grid: Grid, requires_grad: bool):
        """The per-particle affine matrices of a substep: the grid's own array under a tape
        (the tape reads it in backward), else one reused array (fresh ones cost page faults
        every substep). Its adjoint is not zeroed here: it starts at zero, and a complete
        backward consumes it (the stress adjoints zero what they read); after an
        incomplete one, ``Grid.zero_grad`` does."""
        wp = self.wp
        p = self.model.particle_count
        tape = _active_tape()
        owner = grid if (tape is not None and grid.requires_grad) else self
        a = owner.affine
        if a is None or a.shape[0] != p or a.requires_grad != requires_grad:
            a = owner.affine = wp.empty(
                p, dtype=wp.mat33, device=self.model.device, requires_grad=requires_grad
            )
        return a

    def _elastic_stress(
        self, state_in: State, state_out: State, affine, grid: Grid, dt: float
    ) -> None:
        """Stress of the elastic particles with ``kernels._stress_elastic`` (fast polar rotation).

        Under a tape the launch is recorded by hand: the forward stores the polar rotation R
        of each particle's trial F in ``grid.rotation`` and the backward launches the
        hand-written ``_stress_elastic_adjoint`` (R read back: no SVD) on the chunks' threads,
        or Warp's adjoint of ``_stress_elastic_replay`` when some adjoint buffers are missing.
        """
        wp = self.wp
        m = self.model
        dev = m.device
        tape = _active_tape()
        outputs = [state_out.F, state_out.ep, affine]

        if tape is None:
            if self._R_dummy is None:
                self._R_dummy = wp.empty(1, dtype=wp.mat33, device=dev)
            self._chunked(
                lambda c, start, n: wp.launch(
                    _k._stress_elastic,
                    dim=n,
                    inputs=[*self._elastic_args(state_in, dt, start), 0],
                    outputs=[*outputs, self._R_dummy],
                    device=dev,
                )
            )
            return
        R = self._rotation(grid)
        self._chunked(
            lambda c, start, n: self._rebinds.launch(
                _k._stress_elastic,
                n,
                [*self._elastic_args(state_in, dt, start), 1],
                [*outputs, R],
            )
        )
        self._record_elastic_stress(tape, state_in, state_out, affine, R, dt)

    def _launch_untaped(self, kernel, dim, inputs: list, outputs: list) -> None:
        """``wp.launch`` that no tape records (packed once per call site, re-bound)."""
        self._rebinds.launch(kernel, dim, inputs, outputs)

    def _rotation(self, grid: Grid):
        """``grid.rotation``: where a recorded substep stores its elastic rotations."""
        p = self.model.particle_count
        R = grid.rotation
        if R is None or R.shape[0] != p:
            R = grid.rotation = self.wp.empty(p, dtype=self.wp.mat33, device=self.model.device)
        return R

    def _record_elastic_stress(
        self, tape, state_in: State, state_out: State, affine, R, dt: float
    ) -> None:
        """Record the elastic stress's adjoint (``_elastic_stress_backward``) on ``tape``."""
        wp = self.wp
        outputs = [state_out.F, state_out.ep, affine]
        arrays = [*self._elastic_args(state_in, dt, 0), *outputs]
        tape.record_func(
            backward=_Call(
                (Solver._elastic_stress_backward, self, tape, state_in, state_out, affine, R, dt)
            ),
            arrays=[a for a in arrays if isinstance(a, wp.array) and a.grad is not None],
        )

    def _elastic_args(self, state_in: State, dt: float, start: int) -> list:
        """Inputs of ``kernels._stress_elastic`` but its last (store R): C F ep active volume
        density class E nu; dx dt start."""
        full = self._stress_args(state_in, dt, start)
        return [*full[:9], *full[15:]]

    def _elastic_stress_backward(
        self, tape, state_in: State, state_out: State, affine, R, dt: float
    ) -> None:
        pr = self.model.params
        outputs = [state_out.F, state_out.ep, affine]
        grads = [state_in.C.grad, state_in.F.grad, state_in.ep.grad]
        grads += [pr[k].grad for k in ("density", "E", "nu")]
        hand = all(g is not None for g in (*grads, *(o.grad for o in outputs)))

        # chunks write disjoint particles: no shared adjoints
        def adj(c: int, start: int, n: int) -> None:
            ins = [*self._elastic_args(state_in, dt, start), R]
            if hand:  # the hand-written adjoint (every adjoint buffer present)
                self._rebinds.launch(
                    _k._stress_elastic_adjoint, n, [*ins, *(o.grad for o in outputs)], grads
                )
                return
            self._rebinds.launch(
                _k._stress_elastic_replay,
                n,
                ins,
                outputs,
                [tape.get_adjoint(a) for a in ins],
                [tape.get_adjoint(o) for o in outputs],
                adjoint=True,
            )

        self._chunked(adj)

    def _p2g(self, state_in: State, affine, mv, wp_off) -> None:
        """P2G scatter over the chunks; under a tape, records the hand-written adjoint
        ``_p2g_adjoint`` (chunks read their own private adjoint grid, write disjoint particles)."""
        wp = self.wp
        dev = self.model.device
        tape = _active_tape()
        density = self.model.params["density"]
        needed = [state_in.x, state_in.v, affine, density, mv]
        custom = tape is not None and all(a.grad is not None for a in needed)
        if custom:  # its adjoint is recorded by hand just below
            self._chunked(
                lambda c, start, n: self._rebinds.launch(
                    _k._p2g, n, self._p2g_args(state_in, affine, wp_off, c, start), [mv]
                )
            )
            self._record_p2g(tape, state_in, affine, mv, wp_off)
            return
        self._chunked(
            lambda c, start, n: wp.launch(
                _k._p2g,
                dim=n,
                inputs=self._p2g_args(state_in, affine, wp_off, c, start),
                outputs=[mv],
                device=dev,
            )
        )

    def _record_p2g(self, tape, state_in: State, affine, mv, wp_off) -> None:
        """Record P2G's hand-written adjoint (``_p2g_backward``) on ``tape``."""
        density = self.model.params["density"]
        tape.record_func(
            backward=_Call((Solver._p2g_backward, self, state_in, affine, mv, wp_off)),
            arrays=[state_in.x, state_in.v, affine, density, mv],
        )

    def _p2g_backward(self, state_in: State, affine, mv, wp_off) -> None:
        density = self.model.params["density"]

        def adj(c: int, start: int, n: int) -> None:
            self._rebinds.launch(
                _k._p2g_adjoint,
                n,
                [*self._p2g_args(state_in, affine, wp_off, c, start), mv.grad],
                [state_in.x.grad, state_in.v.grad, affine.grad, density.grad],
            )

        self._chunked(adj)

    def _g2p_args(self, state_in: State, grid: Grid, dt: float, start: int) -> list:
        """Inputs of ``kernels._g2p`` for the chunk at ``start``."""
        m = self.model
        return [
            state_in.x,
            grid.velocity,
            self._lo,
            m.dx,
            dt,
            self._dims,
            self._x_min,
            self._x_max,
            start,
            self._object_id,
            int(m.grid_dims[0]) if self.num_objects > 1 else 0,
        ]

    def _g2p(self, state_in: State, grid: Grid, state_out: State, dt: float) -> None:
        """G2P over the chunks; under a tape, records the hand-written adjoint ``_g2p_adjoint``
        (both chunks scatter node adjoints: private buffers per chunk, then summed)."""
        wp = self.wp
        m = self.model
        dev = m.device
        tape = _active_tape()
        outputs = [state_out.x, state_out.v, state_out.C]
        needed = [state_in.x, grid.velocity, *outputs]
        custom = tape is not None and self._g2p_custom(state_in, grid, state_out)
        # (with a tape but some arrays without gradients, Warp records its own adjoint)
        if tape is None:  # packed launches replayed
            self._chunked(
                lambda c, start, n: self._replays.launch(
                    _k._g2p, n, self._g2p_args(state_in, grid, dt, start), outputs
                )
            )
            return
        if not custom:  # Warp records its own adjoint
            self._chunked(
                lambda c, start, n: wp.launch(
                    _k._g2p,
                    dim=n,
                    inputs=self._g2p_args(state_in, grid, dt, start),
                    outputs=outputs,
                    device=dev,
                )
            )
            return
        self._chunked(
            lambda c, start, n: self._rebinds.launch(
                _k._g2p, n, self._g2p_args(state_in, grid, dt, start), outputs
            )
        )
        v_g2p = grid.v_g2p
        if v_g2p is None or v_g2p.shape[0] != m.particle_count:
            v_g2p = grid.v_g2p = wp.empty(m.particle_count, dtype=wp.vec3, device=dev)
        copy_array(v_g2p, state_out.v)  # before the post-G2P hooks edit state_out.v
        shape = tuple(grid.mv.shape[1:]) if grid.mv is not None else tuple(m.grid_dims)
        tape.record_func(
            backward=_Call(
                (
                    Solver._g2p_backward,
                    self,
                    state_in,
                    grid,
                    state_out,
                    dt,
                    v_g2p,
                    grid.offset,
                    shape,
                )
            ),
            arrays=needed,
        )

    @staticmethod
    def _g2p_custom(state_in: State, grid: Grid, state_out: State) -> bool:
        """Whether a recorded G2P records its hand-written adjoint (every adjoint buffer
        present; else Warp records its own)."""
        return all(
            a.grad is not None
            for a in (state_in.x, grid.velocity, state_out.x, state_out.v, state_out.C)
        )

    def _g2p_backward(
        self, state_in: State, grid: Grid, state_out: State, dt: float, v_g2p, offset, shape
    ) -> None:
        grid.clean = None  # scatters into the node velocity adjoint
        # chunk 0 scatters straight into the grid's adjoint; chunk 1 (CPU threads) into a
        # region-sized private buffer (the particles' stencils lie in the region), reused,
        # then added at the offset: Warp's CPU atomics are plain read-modify-writes
        wp = self.wp
        off = wp.vec3i(*offset)
        zero = wp.vec3i(0, 0, 0)
        private, poffs = [grid.velocity.grad], [zero]
        if self.chunks > 1:
            private += self._private_grids(shape)
            poffs.append(off)

        def adj(c: int, start: int, n: int) -> None:
            self._rebinds.launch(
                _k._g2p_adjoint,
                n,
                [
                    *self._g2p_args(state_in, grid, dt, start),
                    v_g2p,
                    state_out.x.grad,
                    state_out.v.grad,
                    state_out.C.grad,
                    poffs[c],
                ],
                [state_in.x.grad, private[c]],
            )

        self._chunked(adj)
        if self.chunks > 1:
            for g in private[1:]:
                self._rebinds.launch(
                    _k._add_region_vec3,
                    tuple(g.shape[:2]),  # (i, j) rows, each looping over k
                    [g, off],
                    [grid.velocity.grad],
                )

    def _private_grids(self, shape: tuple[int, ...]) -> list:
        """Zeroed region-sized vec3 buffers, one per chunk after the first (reused while the
        shape fits)."""
        wp = self.wp
        bufs = self._private
        if not bufs or any(tuple(b.shape) != tuple(shape) for b in bufs):
            bufs = self._private = [
                wp.zeros(shape, dtype=wp.vec3, device=self.model.device)
                for _ in range(self.chunks - 1)
            ]
        else:
            for b in bufs:
                b.zero_()
        return bufs

    def max_speed(self, state: State) -> float:
        """Largest particle speed [m/s]; inf when any velocity is NaN/Inf."""
        wp = self.wp
        out = wp.zeros(1, dtype=float, device=self.model.device)
        wp.launch(
            _k._max_speed_sq,
            dim=state.particle_count,
            inputs=[state.v, out],
            device=self.model.device,
            record_tape=False,
        )
        s = float(out.numpy()[0])
        return math.inf if s >= 1.0e30 else math.sqrt(s)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None


def wave_speeds(values: dict[str, Any]) -> np.ndarray:
    """P-wave speed [m/s] per particle (or scalar) of sim-unit material values.

    Solids: sqrt((lambda + 2 mu) / rho) from E, nu; Newtonian fluid: sqrt(kappa / rho);
    non-Newtonian: sqrt((kappa + 4/3 mu) / rho).
    """
    from motionphysics.sim.model import material_arrays

    count = _count(values)
    ids, p = material_arrays(values, count)
    E, nu, rho = (
        p["E"].astype(np.float64),
        p["nu"].astype(np.float64),
        p["density"].astype(np.float64),
    )
    lam_2mu = E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))
    modulus = np.where(ids <= 4, lam_2mu, 0.0)
    modulus = np.where(ids == 5, p["kappa"], modulus)
    modulus = np.where(ids == 6, p["kappa"] + 4.0 / 3.0 * p["mu"], modulus)
    return np.sqrt(np.maximum(modulus, 0.0) / rho)


def _count(values: dict[str, Any]) -> int:
    for v in values.values():
        if hasattr(v, "detach"):
            v = v.detach().cpu().numpy()
        a = np.asarray(v)
        if a.ndim >= 1 and a.dtype.kind not in "US":
            return int(a.shape[0])
        if a.ndim >= 1:
            return int(a.shape[0])
    return 1


def stable_dt(values: dict[str, Any], dx: float, cfl: float = DEFAULT_CFL) -> float:
    """Largest substep [s] satisfying the CFL condition c dt / dx <= cfl of the stiffest
    material and the explicit viscosity limit dt <= 0.5 rho dx^2 / (6 mu) (Newtonian)."""
    from motionphysics.sim.model import material_arrays

    c = float(np.max(wave_speeds(values)))
    dt = math.inf if c <= 0 else cfl * dx / c
    ids, p = material_arrays(values, _count(values))
    visc = ids == 5
    if np.any(visc & (p["mu"] > 0)):
        ratio = np.max(np.where(visc, p["mu"] / p["density"], 0.0))
        dt = min(dt, 0.5 * dx * dx / (6.0 * float(ratio)))
    return dt


def auto_substeps(
    values: dict[str, Any], dx: float, frame_dt: float, cfl: float = DEFAULT_CFL
) -> int:
    """Smallest substep count per frame whose dt = frame_dt / n satisfies :func:`stable_dt`.

    ``values``: sim-unit material dict (``'class'`` + parameters, scalars or per particle).
    """
    dt = stable_dt(values, dx, cfl)
    if not math.isfinite(dt):
        return 1
    return max(1, math.ceil(frame_dt / dt * (1.0 - 1e-9)))


def cfl_number(values_or_model: Any, dx: float, dt: float) -> float:
    """max wave speed * dt / dx for a material dict or a :class:`Model`."""
    if isinstance(values_or_model, Model):
        mm = values_or_model
        values = {
            "class": mm.material_class.numpy(),
            **{k: a.numpy() for k, a in mm.params.items()},
        }
    else:
        values = values_or_model
    return float(np.max(wave_speeds(values))) * dt / dx
