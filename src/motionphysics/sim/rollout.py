"""Frame rollouts with bounded-memory gradients (checkpointing) and truncated modes.

Forward (:meth:`Rollout.forward`): runs ``substeps`` solver steps per frame without a
tape, checks every frame for NaN / runaway velocities (:class:`SimulationError` naming
the frame and the CFL number), and stores one state checkpoint per frame boundary
(P x 100 bytes each).

Backward (:meth:`Rollout.backward`), given adjoints of the loss with respect to x, v,
F at chosen frames:

- ``full``: for each frame segment, last first, recompute the segment from its
  checkpoint under a ``wp.Tape`` (one state and one grid per substep) and propagate
  the state adjoint through it. A forward run with ``record_tapes=True`` records the
  trailing frames whose tapes fit ``tape_memory`` as it goes, and the backward starts
  from those tapes instead of recomputing them (with the whole rollout kept, a full
  backward costs the adjoint kernels only). When a segment's tape would exceed ``tape_memory``,
  its substep states are recomputed without a tape and each substep is re-recorded on
  its own tape in reverse (one grid in memory, one extra forward pass). Memory is
  independent of the number of frames either way.
- ``window``: for each supervised frame, gradients flow through its last ``window``
  substeps only; the state before them is treated as constant.
- ``last_substep``: ``window`` with one substep (the paper's truncated mode).

Gradients accumulate into the ``.grad`` buffers of the model's parameter arrays (and
of any boundary arrays recorded by the hooks); the adjoint of the initial state is
returned (its ``v`` is the initial-velocity gradient).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from motionphysics.errors import SimulationError
from motionphysics.runtime import init_warp
from motionphysics.sim.solver import Solver, cfl_number
from motionphysics.sim.state import State

GradMode = Literal["full", "window", "last_substep"]

WALL_REACH_CELLS = 0.5
"""Material within this many cells of a domain wall has reached it (walls hold particles
exactly on them; bodies resting against a wall's grid nodes stay within ~0.5 cell)."""

RUNAWAY_CELLS_PER_SUBSTEP = 1.0
"""A particle faster than this many cells per substep (v dt / dx) means divergence."""


@dataclass
class RolloutResult:
    """Host copies of the frames of one rollout (frame 0 is the initial state).

    Attributes:
        xs: positions [m], shape (T, P, 3), float32.
        Fs: deformation gradients [-], shape (T, P, 3, 3), float32.
        vs: velocities [m/s], shape (T, P, 3), float32, or None when not asked for.
        active: 1 = simulated, 0 = removed by a ``cut`` collider, shape (T, P), float32
            (removed particles stay where they were removed: renderers hide them).
        wall_hits: the first frame each domain wall was reached, ``[{"frame": f, "wall":
            "x-" | "x+" | "y-" | ... }]`` by frame (walls that a collider plane covers,
            e.g. a floor on the domain's lower face, are not reported).
    """

    xs: np.ndarray
    Fs: np.ndarray
    vs: np.ndarray | None = None
    active: np.ndarray | None = None
    wall_hits: list = field(default_factory=list)


class Rollout:
    """Runs frames of a :class:`Solver` and back-propagates losses on them."""

    def __init__(
        self, solver: Solver, substeps: int, frame_dt: float, tape_memory: int | None = None
    ):
        """``tape_memory`` [bytes]: the most memory tapes may hold at once (see
        :meth:`_span_bytes`): the frames a forward keeps recorded together, and the largest
        span a backward records at once (spans that need more use the step-wise
        recomputation). Default :func:`default_tape_memory`."""
        if substeps < 1:
            raise ValueError("substeps must be >= 1")
        self.wp = init_warp()
        self.solver = solver
        self.model = solver.model
        self.substeps = int(substeps)
        self.frame_dt = float(frame_dt)
        self.dt = self.frame_dt / self.substeps
        self.tape_memory = int(default_tape_memory() if tape_memory is None else tape_memory)
        self.checkpoints: list[State] = []
        self._owner: Any = None  # the bridge call whose forward produced the checkpoints
        # frame f -> (tape, states, buffers) recorded by forward(record_tapes=True) for the backward
        self._kept: dict[int, tuple[Any, list[State], dict]] = {}

    def release_scratch(self) -> None:
        """Free the state / grid buffers that :meth:`backward` keeps for its next call."""
        ctx = getattr(self.solver, "_rollout_buffers", None)
        if ctx is not None and ctx.get("owner") is not None and ctx["owner"]() is self:
            self.solver._rollout_buffers = None
        self._kept = {}

    @property
    def kept_frames(self) -> list[int]:
        """Frames whose substeps the last forward kept on tapes for the next full backward."""
        return sorted(self._kept)

    def _context(self) -> dict[str, Any]:
        """The backward's and the recording forward's buffers (kept between calls: fresh
        ones cost page faults, ~5 ms per substep at 20k particles, 64^3, and a refinement
        allocating ~400 substeps of them spent ~1 s per iteration in ``wp.zeros``);
        :meth:`release_scratch` frees them.

        They belong to the solver, not to this rollout: a rollout made again for a new
        substep count (``sim.substeps: auto`` re-resolved as E changes) reuses them. The
        rollout that used them last owns them; when another one takes them, the tapes the
        previous owner kept record into these buffers and are dropped (its next full
        backward recomputes those frames from its checkpoints)."""
        m = self.model
        p = m.particle_count
        ctx = getattr(self.solver, "_rollout_buffers", None)
        if ctx is None or ctx["particles"] != p:
            ctx = self.solver._rollout_buffers = {
                "particles": p,
                "owner": None,
                "work": State.zeros(p, m.device),
                "scratch": State.zeros(p, m.device),
                "sin": State.zeros(p, m.device, requires_grad=True),
                "sout": State.zeros(p, m.device, requires_grad=True),
            }
        owner = ctx["owner"]() if ctx["owner"] is not None else None
        if owner is not self:
            if owner is not None:
                owner._kept = {}
            ctx["owner"] = weakref.ref(self)
        return ctx

    # ----------------------------------------------------------------- forward
    def _substep(self, state_in: State, state_out: State, k: int, grid=None) -> None:
        self.solver.step(state_in, state_out, self.dt, t=k * self.dt, substep=k, grid=grid)

    def check(self, state: State, frame: int) -> None:
        """Raise :class:`SimulationError` when ``state`` has NaN/Inf or runaway velocities."""
        speed = self.solver.max_speed(state)
        limit = RUNAWAY_CELLS_PER_SUBSTEP * self.model.dx / self.dt
        if not np.isfinite(speed) or speed > limit:
            cfl = cfl_number(self.model, self.model.dx, self.dt)
            what = (
                "NaN/Inf values" if not np.isfinite(speed) else f"runaway velocity {speed:.3g} m/s"
            )
            raise SimulationError(
                f"simulation diverged at frame {frame} ({what}); likely cause: the time step is too "
                f"large for the stiffness (CFL number max wave speed * dt / dx = {cfl:.3g} with "
                f"dt = {self.dt:.3g} s, dx = {self.model.dx:.3g} m; keep it below ~0.4): use more "
                "substeps (sim.substeps: auto), a softer material, or a coarser grid"
            )

    def forward(
        self,
        state0: State,
        num_frames: int,
        keep_velocities: bool = False,
        keep_checkpoints: bool = True,
        check: bool = True,
        record_tapes: bool = False,
    ) -> RolloutResult:
        """Run ``num_frames - 1`` frames from ``state0`` (left unchanged); frame 0 = ``state0``.

        ``record_tapes`` (with ``keep_checkpoints``): a ``grad_mode='full'`` backward follows,
        so the trailing frames whose tapes fit ``tape_memory`` together are recorded now,
        as they are simulated, and that backward starts from their tapes instead of
        recomputing them (the other frames are recomputed from their checkpoints as
        usual). The positions are the same either way (a recorded step runs the same
        kernels on the same inputs); :attr:`kept_frames` lists the recorded frames.
        """
        if num_frames < 1:
            raise ValueError("num_frames must be >= 1")
        p = self.model.particle_count
        xs = np.empty((num_frames, p, 3), np.float32)
        Fs = np.empty((num_frames, p, 3, 3), np.float32)
        vs = np.empty((num_frames, p, 3), np.float32) if keep_velocities else None
        active = np.empty((num_frames, p), np.float32)
        walls = _WallWatch(self.model)
        self._owner = None
        self._kept = {}
        S = self.substeps
        a = state0.clone(requires_grad=False)
        b = State.zeros(p, self.model.device)
        self.checkpoints = [a.clone()] if keep_checkpoints else []
        first_taped = num_frames  # no frame recorded
        if record_tapes and keep_checkpoints and num_frames > 1:
            # as many trailing frames as the estimate of the first lets fit (the estimate
            # allows 1.5x growth of the particles' region; each frame is re-checked below)
            per_frame = self._span_bytes(S, 0)
            first_taped = max(1, num_frames - self.tape_memory // max(per_frame, 1))
        used = 0

        def record(f: int, s: State) -> None:
            xs[f] = s.x.numpy()
            Fs[f] = s.F.numpy()
            active[f] = s.active.numpy()
            if vs is not None:
                vs[f] = s.v.numpy()
            walls.check(f, xs[f], active[f])

        record(0, a)
        for f in range(1, num_frames):
            k0 = (f - 1) * S
            need = self._span_bytes(S, k0) if f >= first_taped else 0
            if f >= first_taped and used + need <= self.tape_memory:
                bufs = self._slot(len(self._kept))
                tape, states = self._record(k0, k0 + S, a, bufs)
                self._kept[f] = (tape, states, bufs)
                used += need
                a.assign(states[S])
            else:
                for s in range(S):
                    self._substep(a, b, k0 + s)
                    a, b = b, a
            if check:
                self.check(a, f)
            if keep_checkpoints:
                self.checkpoints.append(a.clone())
            record(f, a)
        return RolloutResult(xs, Fs, vs, active, walls.hits)

    # ---------------------------------------------------------------- backward
    def _span_bytes(self, n: int, k0: int) -> int:
        """Estimated memory [bytes] of recording substeps k0 .. k0+n-1 on one tape: per substep
        the touched pages of the node-velocity grid, the region-sized vec4 grids (the
        particles' current region, x1.5 for growth), the state and the affine matrices,
        values and adjoints, and the stored rotations of the elastic stress and G2P's
        velocities."""
        m = self.model
        nodes = int(np.prod(m.grid_dims))
        region = nodes
        touched = nodes  # node-velocity entries whose pages a substep touches
        c = k0 // self.substeps
        if c < len(self.checkpoints):
            _, shape = self.solver._region(self.checkpoints[c])
            region = min(nodes, int(1.5 * np.prod(shape)))
            if self.solver.num_objects == 1 and self.wp.get_device(m.device).is_cpu:
                # an uninitialised grid (Solver.make_grid): per x-slab of the region, the
                # rows from its first to its last y (whole z rows), x1.5 for growth
                nz = int(m.grid_dims[2])
                touched = min(nodes, int(1.5 * shape[0] * (shape[1] + 1) * nz))
        state = m.particle_count * (12 + 12 + 36 + 36 + 4 + 4 + 36)
        grid = touched * 12 + region * 16 * self.solver.chunks
        # elastic stress: the stored polar rotations; G2P: its gathered velocities
        stored = m.particle_count * (36 + 12)
        return n * (2 * (grid + state) + stored)

    def _backward_span(self, k0: int, k1: int, adj: State, ctx: dict[str, Any]) -> None:
        """Propagate the adjoint ``adj`` of the state at substep k1 to substep k0 (in place).

        When the span's tape fits ``tape_memory`` the span is recomputed ONCE under one tape
        (one grid and state per substep); otherwise its substep states are recomputed without
        a tape and each substep is re-recorded on its own tape (one grid in memory).
        """
        n = k1 - k0
        if self._kept_frame(k0, k1) is not None or self._span_bytes(n, k0) <= self.tape_memory:
            self._backward_span_taped(k0, k1, adj, ctx)
        else:
            self._backward_span_stepwise(k0, k1, adj, ctx)

    def _kept_frame(self, k0: int, k1: int) -> int | None:
        """The frame whose kept tape covers substeps k0 .. k1-1 exactly, or None."""
        S = self.substeps
        f = k1 // S
        return f if (k0 == (f - 1) * S and k1 == f * S and f in self._kept) else None

    def _start_state(self, k0: int, out: State, ctx: dict[str, Any]) -> None:
        """Write the state at global substep k0 into ``out`` (from the nearest checkpoint)."""
        S = self.substeps
        c = k0 // S
        if c >= len(self.checkpoints):
            raise RuntimeError("Rollout.backward needs the checkpoints of a forward() run")
        out.assign(self.checkpoints[c])
        k = c * S
        if k < k0:
            work, scratch = ctx["work"], ctx["scratch"]
            work.assign(out)
            while k < k0:
                self._substep(work, scratch, k)
                work, scratch = scratch, work
                k += 1
            out.assign(work)

    def _slot(self, j: int) -> dict[str, list]:
        """The ``j``-th set of tape buffers (states and grids) that forward records into;
        kept between calls like the backward's buffers (fresh ones cost page faults)."""
        slots = self._context().setdefault("slots", [])
        while len(slots) <= j:
            slots.append({})
        return slots[j]

    def _record(self, k0: int, k1: int, start: State | None, bufs: dict[str, Any]):
        """Record substeps k0 .. k1-1 on a new tape, one state and grid per substep (from
        ``bufs``, grown as needed); the first state is ``start``, or the state at k0 from
        the checkpoints."""
        n = k1 - k0
        p = self.model.particle_count
        states = bufs.setdefault("tstates", [])
        grids = bufs.setdefault("tgrids", [])
        while len(states) < n + 1:
            states.append(State.zeros(p, self.model.device, requires_grad=True))
        while len(grids) < n:
            grids.append(self.solver.make_grid(requires_grad=True))
        if start is None:
            self._start_state(k0, states[0], self._context())
        else:
            states[0].assign(start)
        # Only the buffers a backward may have left non-zero are zeroed (fresh ones are
        # zero): a complete backward consumes every adjoint it reads (the adjoint kernels
        # zero the output adjoints they take) except the first state's, which holds the
        # result; ``bufs["dirty"]`` counts the leading states that may hold gradients (see
        # _backward_span_taped). Zeroing all of them cost 10 memsets per substep.
        dirty = max(int(bufs.get("dirty", 0)), 1)
        for s in states[:dirty]:
            s.zero_grad()
        for g in grids[: dirty - 1]:
            g.zero_grad()
        bufs["dirty"] = 0
        tape = self.wp.Tape()
        with tape:
            for i in range(n):
                self._substep(states[i], states[i + 1], k0 + i, grid=grids[i])
        return tape, states

    def _backward_span_taped(self, k0: int, k1: int, adj: State, ctx: dict[str, Any]) -> None:
        wp = self.wp
        n = k1 - k0
        frame = self._kept_frame(k0, k1)
        kept = self._kept.pop(frame) if frame is not None else None
        if kept is not None:
            tape, states, bufs = kept  # recorded by forward(record_tapes=True)
        else:
            bufs = ctx
            tape, states = self._record(k0, k1, None, bufs)
        # until the backward has run to its end, any of the span's buffers may hold gradients
        bufs["dirty"] = max(int(bufs.get("dirty", 0)), n + 1)
        for f in State.FIELDS:
            wp.copy(getattr(states[n], f).grad, getattr(adj, f))
        tape.backward()
        for f in State.FIELDS:
            wp.copy(getattr(adj, f), getattr(states[0], f).grad)
        bufs["dirty"] = 1  # every adjoint consumed but the first state's
        # Drop the tape without reset(): reset() would zero the parameters' gradients.
        tape.launches = []

    def _backward_span_stepwise(self, k0: int, k1: int, adj: State, ctx: dict[str, Any]) -> None:
        wp = self.wp
        n = k1 - k0
        p = self.model.particle_count
        pool = ctx.setdefault("pool", [])
        while len(pool) < n:
            pool.append(State.zeros(p, self.model.device))
        # substep states k0 .. k1-1, recomputed without a tape (before each step's hooks)
        self._start_state(k0, pool[0], ctx)
        work, scratch = ctx["work"], ctx["scratch"]
        for i in range(1, n):
            work.assign(pool[i - 1])
            self._substep(work, scratch, k0 + i - 1)
            pool[i].assign(scratch)
        sin, sout = ctx["sin"], ctx["sout"]
        grid = ctx.setdefault("grid", self.solver.make_grid(requires_grad=True))
        for i in reversed(range(n)):
            sin.assign(pool[i])
            sin.zero_grad()
            grid.zero_grad()
            tape = wp.Tape()
            with tape:
                self._substep(sin, sout, k0 + i, grid=grid)
            for f in State.FIELDS:
                wp.copy(getattr(sout, f).grad, getattr(adj, f))
            tape.backward()
            for f in State.FIELDS:
                wp.copy(getattr(adj, f), getattr(sin, f).grad)
            tape.launches = []

    def backward(
        self,
        adjoints: dict[int, dict[str, Any]],
        grad_mode: GradMode = "full",
        window: int = 8,
    ) -> State:
        """Back-propagate frame adjoints; returns the adjoint of the initial state.

        ``adjoints[f]`` maps ``'x'``, ``'v'`` (P, 3) and/or ``'F'`` (P, 3, 3) to dL/d(that
        field at frame f) (numpy / torch / wp arrays). Parameter gradients ACCUMULATE into
        the ``.grad`` buffers of ``model.params`` (zero them first, ``model.zero_grad()``).
        """
        m = self.model
        p = m.particle_count
        S = self.substeps
        if grad_mode not in ("full", "window", "last_substep"):
            raise ValueError(f"grad_mode must be full, window or last_substep, got {grad_mode!r}")
        frames = sorted(f for f in adjoints if f > 0)
        adj0 = State.zeros(p, m.device)
        for f in [f for f in adjoints if f == 0]:
            _add_adjoint(adj0, adjoints[f])
        if not frames:
            return adj0
        if frames[-1] >= len(self.checkpoints):
            raise ValueError(f"adjoint given for frame {frames[-1]} beyond the forward run")
        span = S if grad_mode == "full" else (1 if grad_mode == "last_substep" else int(window))
        if span < 1:
            raise ValueError("window must be >= 1")
        ctx = self._context()
        if grad_mode == "full":
            adj = State.zeros(p, m.device)
            for f in range(frames[-1], 0, -1):
                if f in adjoints:
                    _add_adjoint(adj, adjoints[f])
                self._backward_span((f - 1) * S, f * S, adj, ctx)
            _add_state(adj0, adj)
            return adj0
        self._kept = {}  # kept tapes serve only the full backward
        for f in frames:
            adj = State.zeros(p, m.device)
            _add_adjoint(adj, adjoints[f])
            k1 = f * S
            k0 = max(0, k1 - span)
            self._backward_span(k0, k1, adj, ctx)
            if k0 == 0:
                _add_state(adj0, adj)
        return adj0


def default_tape_memory() -> int:
    """Bytes tapes may hold at once: ``MOTIONPHYSICS_TAPE_MEMORY_GB`` when set, else a
    quarter of the machine's memory, at most 4 GiB (enough to keep every frame of a
    4,000-particle, 32^3, 24-frame fit recorded)."""
    import os

    env = os.environ.get("MOTIONPHYSICS_TAPE_MEMORY_GB")
    if env:
        try:
            gb = float(env)
        except ValueError:
            gb = -1.0
        if not gb > 0:
            raise ValueError(
                f"MOTIONPHYSICS_TAPE_MEMORY_GB: expected a positive number, got {env!r}"
            )
        return int(gb * (1 << 30))
    total = 16 << 30
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        pass
    return int(min(4 << 30, total // 4))


class _WallWatch:
    """Records the first frame in which active material comes within WALL_REACH_CELLS of
    each face of the model's material box (``Model.wall_box``), except faces that a
    collider plane covers (an axis-aligned non-cut ``surface_collider`` facing into the
    box within half a cell of the face). Where the material already is at frame 0 is its
    placement, not a motion: a face it starts within reach of counts only once the
    material comes nearer to it than it started (by a tenth of a cell). A small object
    dropped from high up at a coarse grid starts a fraction of a cell below the top face
    and falls away; it was reported as having reached the top wall at frame 0."""

    NAMES = ("x-", "x+", "y-", "y+", "z-", "z+")

    def __init__(self, model) -> None:
        lo, hi = model.wall_box
        self.lo, self.hi = np.asarray(lo), np.asarray(hi)
        self.reach = WALL_REACH_CELLS * model.dx
        self.closer = 0.1 * model.dx
        self.hits: list[dict] = []
        self.seen: set[str] = set()
        self.start: dict[str, float] = {}  # faces within reach at frame 0: distance then
        prog = getattr(model, "boundary", None)
        for op in getattr(prog, "_plane_ops", ()):
            n = np.asarray(op.scalars["normal"], dtype=np.float64)
            q = np.asarray(op.scalars["point"], dtype=np.float64)
            a = int(np.argmax(np.abs(n)))
            if abs(abs(n[a]) - 1.0) > 1e-6:
                continue
            face, side = (self.lo[a], "-") if n[a] > 0 else (self.hi[a], "+")
            if abs(q[a] - face) <= 0.5 * model.dx:
                self.seen.add("xyz"[a] + side)

    def check(self, frame: int, x: np.ndarray, active: np.ndarray) -> None:
        if len(self.seen) == 6:
            return
        live = x[active > 0]
        if live.size == 0:
            return
        lo, hi = live.min(axis=0), live.max(axis=0)
        for a in range(3):
            for side, dist in (("-", lo[a] - self.lo[a]), ("+", self.hi[a] - hi[a])):
                name = "xyz"[a] + side
                if dist > self.reach or name in self.seen:
                    continue
                if frame == 0:
                    self.start[name] = float(dist)
                elif name not in self.start or dist < self.start[name] - self.closer:
                    self.seen.add(name)
                    self.hits.append({"frame": int(frame), "wall": name})


def _to_wp(value: Any, dtype, device: str):
    wp = init_warp()
    if isinstance(value, wp.array):
        return value
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return wp.array(np.ascontiguousarray(value, dtype=np.float32), dtype=dtype, device=device)


def _add_adjoint(adj: State, fields: dict[str, Any]) -> None:
    wp = init_warp()
    types = {"x": wp.vec3, "v": wp.vec3, "F": wp.mat33, "C": wp.mat33, "ep": float}
    for name, value in fields.items():
        if value is None:
            continue
        if name not in types:
            raise ValueError(f"unknown adjoint field {name!r}; expected x, v, F, C or ep")
        src = _to_wp(value, types[name], adj.x.device)
        _axpy(getattr(adj, name), src)


def _add_state(dst: State, src: State) -> None:
    for f in State.FIELDS:
        _axpy(getattr(dst, f), getattr(src, f))


def _axpy(dst, src) -> None:
    # dst += src for same-shaped warp arrays (host round trip; adjoint sizes are small).
    wp = init_warp()
    out = dst.numpy() + src.numpy().reshape(dst.numpy().shape)
    dst.assign(wp.array(out, dtype=dst.dtype, device=dst.device))
