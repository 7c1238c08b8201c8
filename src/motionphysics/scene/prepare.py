"""From a loaded scene to what the simulator needs: ``prepare(...) -> SimScene``.

Steps, in order (each documented at its function):

1. transform: ``up`` (the capture's vertical axis turned to +z), uniform ``scale``, then
   the ``rotate`` list in order, then ``translate`` (world frame). Rotation turns the
   quaternions and rotates SH bands 1-3 exactly.
2. filter: drop splats with opacity < ``opacity_threshold``, then those outside ``crop``;
   with ``region``, only the splats inside it are simulated and the others (every
   opacity, inside ``crop``) become the static scene (:attr:`SimScene.static_splats`),
   as transformed and nothing else, with its collider (:mod:`motionphysics.scene.region`)
   built on the grid once it is sized.
3. anisotropy regularisation (PhysGaussian): raise the smallest scales so that
   largest / smallest <= ``max_anisotropy``.
4. domain: the given ``sim.domain`` (checked), or fitted around the particles and the
   ground planes; ``dx = longest side / sim.grid``, nodes per axis ``ceil(side/dx)+1``.
5. voxelise at ``dx`` on the simulation grid's cells, flood-fill from outside, and
   (``fill: true``) put one invisible particle at the centre of every interior cell:
   the free cells the splats enclose, and the cells deep inside a capture whose splats
   fill the object that no splat centre reaches (:func:`_body_gaps`). When none is
   added, :attr:`SimScene.fill_note` says why (:func:`_fill_note`).
6. particle volumes from the voxelisation (rule at :func:`_particle_volumes`).
7. downsample to ``max_particles`` evenly in space (:func:`stratified_subset`); every
   visible splat follows its nearest kept particle.

Nothing here simulates or renders; this module must not import warp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from motionphysics.config import SceneConfig, SimConfig
from motionphysics.errors import UserInputError
from motionphysics.scene.gaussians import GaussianScene, quat_multiply, rotmat_to_quat

__all__ = [
    "SimScene",
    "prepare",
    "prepare_objects",
    "selected_means",
    "transform_scene",
    "scene_transform",
    "rotation_matrix",
    "regularise_anisotropy",
    "fit_domain",
    "motion_extent",
    "voxelise",
    "stratified_subset",
    "PAD_CELLS",
    "FILL_SEED",
]

PAD_CELLS = 3
"""Grid cells the solver adds outside the material box (``sim.domain``) on every side:
the quadratic B-spline stencil (2) plus the wall layer of ``bounding_box``."""
FILL_SEED = 0
"""Seed of the deterministic subsampling (interior cap, particle downsampling)."""
_CLOSE_CELLS = 1
"""Gaps of up to 2 cells in a splat shell are bridged before the fill (morphological closing)."""
_MAX_SAMPLE_HALF = 4
"""Samples per splat axis in the voxelisation: at most 2*4+1 (bounds the work per splat)."""


@dataclass
class SimScene:
    """A scene ready for MPM: visible splats, simulated particles, and the grid.

    All tensors are float32 on CPU unless stated; world frame (z up) in metres.
    """

    splats: GaussianScene
    """Visible splats after transform, filter, crop and anisotropy regularisation (N of them)."""
    particles: torch.Tensor
    """Simulated particle positions [m], shape (P, 3): visible-derived first, then interior fill."""
    volumes: torch.Tensor
    """Particle rest volumes [m^3], shape (P,); mass = density * volume."""
    n_interior: int
    """How many of the particles (the last ones) are invisible interior fill."""
    splat_parent: torch.Tensor
    """Index of the particle each splat follows, shape (N,), int64."""
    splat_offset: torch.Tensor
    """Rest offset splat mean - parent position [m], shape (N, 3)."""
    domain_lo: torch.Tensor
    """Position of grid node (0,0,0) [m], shape (3,)."""
    domain_hi: torch.Tensor
    """Position of the last grid node, ``domain_lo + (grid_dims - 1) * dx`` [m], shape (3,)."""
    dx: float
    """Grid spacing [m]."""
    grid_dims: tuple[int, int, int]
    """Grid nodes per axis (nx, ny, nz)."""
    source_to_world: torch.Tensor
    """The scene transform as a 4x4 float64 matrix: x_world = s R x_source + t (e.g. for
    INRIA cameras, which live in the source frame)."""
    total_volume: float
    """Occupied volume of the voxelisation [m^3] (= volumes.sum() up to rounding)."""
    wall_lo: torch.Tensor | None = None
    """Low corner of the material box [m], shape (3,): ``sim.domain`` as given, or the
    fitted box; its faces are walls (the grid extends PAD_CELLS cells beyond them)."""
    wall_hi: torch.Tensor | None = None
    """High corner of the material box [m], shape (3,)."""
    object_id: torch.Tensor | None = None
    """Object index of each particle, shape (P,), int64, or None (one object). ``prepare``
    makes one object; a scene of several objects concatenates their particles and sets
    this (``sim.build_simulation`` reads it: one grid velocity field per object)."""
    fill_note: str | None = None
    """With ``fill: true`` and no interior particle: why, and what it means for the run
    (one line; :func:`_fill_note`). None otherwise."""
    fill_hollow: bool = False
    """True when ``fill_note`` says the object is simulated hollow (no enclosed cell)."""
    static_splats: GaussianScene | None = None
    """With ``scene.region``: the splats outside it (S of them), world frame, exactly as
    transformed (no opacity filter, no anisotropy regularisation): drawn and exported
    unchanged in every frame. None without a region."""
    static_collider: object | None = None
    """With ``scene.region`` (and ``static_collider`` not ``off``): the static splats near
    the grid as a fixed collider (:class:`motionphysics.scene.region.StaticCollider`), or
    None (no region, off, or no static splat on the grid)."""
    static_note: str | None = None
    """One line when the static scene under the simulated splats is too sparse to hold
    them (:func:`motionphysics.scene.region.support_note`), else None."""

    @property
    def n_particles(self) -> int:
        return int(self.particles.shape[0])

    @property
    def n_visible(self) -> int:
        """Particles that came from visible splats (the first ones)."""
        return self.n_particles - self.n_interior


# ---- 1. transform ------------------------------------------------------------------


def rotation_matrix(axis: str, degrees: float) -> np.ndarray:
    """Right-handed rotation by ``degrees`` about world ``axis`` ('x','y','z'), float64 (3,3)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    raise UserInputError(f"scene.rotate: axis must be 'x', 'y' or 'z', got {axis!r}")


def scene_transform(scene_cfg) -> np.ndarray:
    """The 4x4 float64 matrix ``x_world = s R x_source + t`` of a scene config's
    ``up``, ``scale``, ``rotate`` and ``translate`` (what :func:`transform_scene` applies;
    a capture's cameras follow it into the world)."""
    from motionphysics.scene.region import up_rotation

    r = up_rotation(getattr(scene_cfg, "up", "z"))
    for axis, deg in scene_cfg.rotate:
        r = rotation_matrix(axis, float(deg)) @ r
    m = np.eye(4)
    m[:3, :3] = float(scene_cfg.scale) * r
    m[:3, 3] = np.asarray(scene_cfg.translate, dtype=np.float64)
    return m


def transform_scene(
    scene: GaussianScene, scale: float = 1.0, rotate=(), translate=(0.0, 0.0, 0.0), up="z"
) -> tuple[GaussianScene, np.ndarray]:
    """Turn ``up`` (the capture's vertical axis: ``scene.up``) to +z, apply scale, then each
    rotation of ``rotate`` ([axis, degrees], in order), then translate.

    Returns the transformed scene (same dtype) and the 4x4 float64 matrix of the transform.
    Means and quaternions are computed in float64; SH bands >= 1 are rotated exactly.
    """
    from motionphysics.scene.region import up_rotation

    r = up_rotation(up)
    for axis, deg in rotate:
        r = rotation_matrix(axis, float(deg)) @ r
    t = np.asarray(translate, dtype=np.float64)
    dtype = scene.means.dtype
    rt = torch.from_numpy(r)
    if np.array_equal(r, np.eye(3)) and float(scale) == 1.0 and not t.any():
        # the identity keeps every bit (a signed zero included): a static scene of
        # scene.region is then the input file's splats exactly
        means = scene.means.clone()
    else:
        means = (scene.means.double() * float(scale) @ rt.T + torch.from_numpy(t)).to(dtype)
    out = GaussianScene(
        means=means,
        log_scales=scene.log_scales.clone() if scale == 1.0 else scene.log_scales + math.log(scale),
        quats=scene.quats.clone(),
        logit_opacities=scene.logit_opacities.clone(),
        sh=scene.sh.clone(),
    )
    if not np.allclose(r, np.eye(3), atol=0.0):
        q_r = rotmat_to_quat(rt)  # unit, so |q_r ⊗ q| = |q| keeps the storage magnitude
        out.quats = quat_multiply(q_r[None, :], scene.quats.double()).to(dtype)
        from motionphysics.scene.sh import rotate_sh

        out.sh = rotate_sh(scene.sh.double(), rt).to(scene.sh.dtype)
    m = np.eye(4)
    m[:3, :3] = float(scale) * r
    m[:3, 3] = t
    return out, m


# ---- 3. anisotropy -------------------------------------------------------------------


def regularise_anisotropy(scene: GaussianScene, max_ratio: float) -> GaussianScene:
    """Raise scales below ``largest / max_ratio`` to that value (per splat), as PhysGaussian.

    Only the smallest axes grow; the largest axis and the orientation are unchanged.
    """
    out = scene.clone()
    floor = scene.log_scales.max(dim=1, keepdim=True).values - math.log(max_ratio)
    out.log_scales = torch.maximum(scene.log_scales, floor)
    return out


# ---- 4. domain ------------------------------------------------------------------------


def _get(bc, key, default=None):
    return bc.get(key, default) if isinstance(bc, dict) else getattr(bc, key, default)


def _grid_from_box(
    lo: np.ndarray, hi: np.ndarray, grid: int
) -> tuple[float, tuple[int, int, int], np.ndarray]:
    side = hi - lo
    dx = float(side.max()) / grid
    # The 1e-9 guard keeps the longest axis at exactly grid+1 nodes despite rounding.
    dims = tuple(int(math.ceil(s / dx - 1e-9)) + 1 for s in side)
    return dx, dims, lo + (np.asarray(dims) - 1) * dx


MOTION_CAP = 4.0
"""The fitted domain grows along the motion the config implies by at most this many
object extents per side (beyond it the resolution would collapse; the rollout reports
the wall reached, and ``sim.domain`` can be given instead)."""
FLUID_SPREAD = {"sand": 2.0, "newtonian": 3.0, "non_newtonian": 2.0}
"""Sideways spread of a collapsing column, in object heights per side (dam-break fronts
run out ~2-4 column heights within a few collapse times; sand's run-out is shorter)."""


def motion_extent(
    sim_cfg, forces=(), boundary_conditions=(), material_class=None, height: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """How far [m] the material may move from its start, per axis, ``(down (3,) <= 0,
    up (3,) >= 0)``: the ballistic path of its centre over the simulated time
    ``(frames - 1) frame_dt`` under ``initial_velocity``, gravity (only when a collider
    plane faces it: else the domain's lower wall is the floor), ``add_constant_force``
    (over its window) and ``add_impulse`` (a velocity change at its start), motion into an
    axis-aligned collider plane stopped there by the caller; plus the sideways spread of a
    fluid or sand column of ``height`` [m] (``FLUID_SPREAD``, perpendicular to gravity)."""
    T = max(0.0, (int(sim_cfg.frames) - 1) * float(sim_cfg.frame_dt))
    steps = 400
    h = T / steps if T > 0 else 0.0
    v = np.asarray(sim_cfg.initial_velocity, dtype=np.float64).copy()
    g = np.asarray(sim_cfg.gravity, dtype=np.float64)
    floors = [
        bc
        for bc in boundary_conditions
        if _get(bc, "type") == "surface_collider"
        and _get(bc, "mode") != "cut"
        and float(np.dot(np.asarray(_get(bc, "normal", (0.0, 0.0, 1.0)), dtype=np.float64), g)) < 0
    ]
    if not floors:
        # nothing stops a fall: the domain's lower wall is the floor, as it always was
        # (growing the domain would only coarsen the grid; the rollout reports the wall)
        g = np.zeros(3)
    pos = np.zeros(3)
    lo, hi = np.zeros(3), np.zeros(3)
    kicks = []
    accels = []
    for f in forces:
        kind = _get(f, "type")
        if _get(f, "unit", "seconds") == "substeps":
            continue  # (substep windows: too short to move the domain)
        end = _get(f, "end", None)  # (null: an impulse at start, or a window that never ends)
        start, end = float(_get(f, "start", 0.0)), 1e9 if end is None else float(end)
        vec = np.asarray(_get(f, "force", (0.0, 0.0, 0.0)), dtype=np.float64)
        if kind == "add_impulse":
            kicks.append((start, vec))
        elif kind == "add_constant_force":
            accels.append((start, end, vec))
    for i in range(steps):
        t = i * h
        for start, dv in kicks:
            if t <= start < t + h:
                v = v + dv
        a = g.copy()
        for start, end, acc in accels:
            if start <= t < end:
                a = a + acc
        v = v + h * a
        pos = pos + h * v
        lo, hi = np.minimum(lo, pos), np.maximum(hi, pos)
    spread = FLUID_SPREAD.get(material_class or "", 0.0) * float(height)
    if spread > 0:
        gn = float(np.linalg.norm(g))
        down = g / gn if gn > 0 else np.array([0.0, 0.0, -1.0])
        side = np.sqrt(np.clip(1.0 - down**2, 0.0, 1.0))  # weight of each axis across gravity
        lo, hi = lo - spread * side, hi + spread * side
    return lo, hi


def _height(points: np.ndarray, gravity) -> float:
    """Extent [m] of ``points`` along gravity (the largest extent without gravity)."""
    g = np.asarray(gravity, dtype=np.float64)
    n = float(np.linalg.norm(g))
    if not n > 0:
        return float(np.ptp(points, axis=0).max())
    return float(np.ptp(points @ (g / n)))


def fit_domain(
    points: np.ndarray,
    grid: int,
    boundary_conditions=(),
    fallback_extent: float = 1e-3,
    motion: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, float, tuple[int, int, int], np.ndarray]:
    """Fitted domain around particles ``points (P,3)`` [m] and the ground planes.

    Bounding box of the points, grown by 0.5 x its largest extent on every side, then
    extended to contain, for every ``surface_collider``, the point of its plane nearest
    to the box centre (so a ground plane below a floating object is inside), then padded
    by PAD_CELLS cells on every side. ``motion`` = :func:`motion_extent`'s ``(down,
    up)`` [m]: the box (before the 0.5 extent margin) first grows by it, at most
    ``MOTION_CAP`` extents per side and not through an axis-aligned collider plane the
    object is in front of. With the padding included, ``dx = longest side /
    grid`` (so ``dx = longest unpadded side / (grid - 2*PAD_CELLS)``). When the points'
    extent is negligible (one splat) ``fallback_extent`` [m] stands in for it.
    Returns (domain_lo (3,), dx, grid_dims, domain_hi (3,)).
    """
    lo = points.min(axis=0).astype(np.float64)
    hi = points.max(axis=0).astype(np.float64)
    ext = float((hi - lo).max())
    if not ext >= 1e-6 * max(fallback_extent, float(np.abs(points).max())):
        ext = fallback_extent  # a single point (or all at one place): size from the splats
    centre = 0.5 * (lo + hi)
    if motion is not None:
        down = np.maximum(np.asarray(motion[0], dtype=np.float64), -MOTION_CAP * ext)
        up = np.minimum(np.asarray(motion[1], dtype=np.float64), MOTION_CAP * ext)
        lo, hi = _stop_at_planes(lo, hi, lo + down, hi + up, boundary_conditions)
    lo = lo - 0.5 * ext
    hi = hi + 0.5 * ext
    for bc in boundary_conditions:
        if _get(bc, "type") != "surface_collider" or _get(bc, "mode") == "cut":
            continue
        p = np.asarray(_get(bc, "point", (0.0, 0.0, 0.0)), dtype=np.float64)
        n = np.asarray(_get(bc, "normal", (0.0, 0.0, 1.0)), dtype=np.float64)
        nn = np.linalg.norm(n)
        if not nn > 0:
            raise UserInputError("boundary_conditions: surface_collider normal must be non-zero")
        n = n / nn
        q = centre - np.dot(centre - p, n) * n  # the plane's point nearest the object
        lo = np.minimum(lo, q)
        hi = np.maximum(hi, q)
    dx = float((hi - lo).max()) / (grid - 2 * PAD_CELLS)
    lo = lo - PAD_CELLS * dx
    hi = hi + PAD_CELLS * dx
    dx, dims, hi = _grid_from_box(lo, hi, grid)
    return lo, dx, dims, hi


WALL_PHASE = 0.5
"""Walls and axis-aligned collider planes sit this fraction of a cell past a grid node.
Grid conditions act on the nodes on or behind a plane, and a body settles against them
at a distance that depends on how the plane falls between nodes: with a plane ON a node
a soft elastic cube came to rest with its lowest particle ~0.8 dx above it, with the plane
half-way between nodes 0.0-0.35 dx above (what a resting body's half particle spacing
explains); fluids and sand flow into the node layer and are projected back onto the plane
after G2P (``boundary_kernels._project_plane``, the G2P wall clamp)."""

GIVEN_DOMAIN_SLACK = 0.5
"""A given ``sim.domain`` may leave the scene's particles up to this many cells outside it
(round-off of a capture resting on the floor face); the first substep projects them in."""


def _given_domain(points: np.ndarray, domain, grid: int):
    """Grid around a given material box ``domain``: ``dx = longest side / grid`` (cells along
    the longest side of the domain, as SimConfig.grid says), the solver's PAD_CELLS added
    OUTSIDE it (see :func:`_aligned_grid`). Returns (dx, wall lo, wall hi)."""
    lo = np.asarray(domain[0], dtype=np.float64)
    hi = np.asarray(domain[1], dtype=np.float64)
    dx = float((hi - lo).max()) / grid
    pmin, pmax = points.min(axis=0), points.max(axis=0)
    slack = GIVEN_DOMAIN_SLACK * dx
    if (pmin < lo - slack).any() or (pmax > hi + slack).any():
        raise UserInputError(
            f"sim.domain: the scene's particles span {np.round(pmin, 4).tolist()} to "
            f"{np.round(pmax, 4).tolist()} m, outside the domain {np.round(lo, 4).tolist()} to "
            f"{np.round(hi, 4).tolist()} (material may only occupy the domain); "
            "enlarge sim.domain or set it to null"
        )
    return dx, lo, hi


def _wall_targets(walls_lo: np.ndarray, walls_hi: np.ndarray, boundary_conditions) -> np.ndarray:
    """Per axis, the plane to put half-way between grid nodes: the first axis-aligned
    (non-cut) ``surface_collider`` plane of that axis inside the material box, else the
    box's low face."""
    target = np.asarray(walls_lo, dtype=np.float64).copy()
    found = [False, False, False]
    for bc in boundary_conditions:
        if _get(bc, "type") != "surface_collider" or _get(bc, "mode") == "cut":
            continue
        n = np.asarray(_get(bc, "normal", (0.0, 0.0, 1.0)), dtype=np.float64)
        p = np.asarray(_get(bc, "point", (0.0, 0.0, 0.0)), dtype=np.float64)
        nn = float(np.linalg.norm(n))
        if not nn > 0:
            continue
        a = int(np.argmax(np.abs(n)))
        if abs(abs(n[a]) / nn - 1.0) > 1e-9 or found[a]:
            continue
        if walls_lo[a] - 1e-9 <= p[a] <= walls_hi[a] + 1e-9:
            target[a] = p[a]
            found[a] = True
    return target


def _aligned_grid(walls_lo, walls_hi, dx: float, targets, dims=None):
    """Grid origin with every target plane half-way between two nodes (``WALL_PHASE``) and at
    least PAD_CELLS cells beyond the walls. Returns (grid lo, dims, grid hi, walls hi):
    ``dims`` given (the fitted domain keeps its node count), the high walls end PAD_CELLS
    cells inside the last node instead."""
    walls_lo = np.asarray(walls_lo, dtype=np.float64)
    walls_hi = np.asarray(walls_hi, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    m = np.ceil((targets - walls_lo) / dx + PAD_CELLS - WALL_PHASE - 1e-9)
    g_lo = targets - (m + WALL_PHASE) * dx
    if dims is None:
        dims = tuple(
            int(math.ceil((h + PAD_CELLS * dx - g) / dx - 1e-9)) + 1
            for g, h in zip(g_lo, walls_hi, strict=True)
        )
    g_hi = g_lo + (np.asarray(dims) - 1) * dx
    walls_hi = np.minimum(walls_hi, g_hi - PAD_CELLS * dx)
    return g_lo, tuple(int(d) for d in dims), g_hi, walls_hi


# ---- 5. voxelisation and fill -------------------------------------------------------------


def voxelise(
    splats: GaussianScene, origin: np.ndarray, dx: float, shape: tuple[int, int, int]
) -> np.ndarray:
    """Cells occupied by splats, shape ``shape`` bool; cell (i,j,k) spans origin + [i,i+1)*dx.

    Each splat marks the cells of points sampled over its one-sigma box (centre ± sigma
    along each of its axes, sigma capped at 4 dx) at spacing <= dx/2, so a surface of
    splats whose neighbours overlap at one sigma becomes a closed layer of cells (no gaps
    for a 6-connected flood fill). The per-splat sample count is bounded (<= 9 per axis):
    no hang on huge or degenerate covariances.
    """
    occ = np.zeros(shape, dtype=bool)
    if splats.num == 0:
        return occ
    means = splats.means.double().numpy()
    axes = splats.rotation_matrices().double().numpy()  # columns = axes, (N,3,3)
    sig = np.minimum(splats.scales.double().numpy(), _MAX_SAMPLE_HALF * dx)  # (N,3), inf -> cap
    sig = np.nan_to_num(sig, nan=0.0)
    half = np.clip(np.ceil(sig / (0.5 * dx)), 0, _MAX_SAMPLE_HALF).astype(np.int64)  # (N,3)
    dims = np.asarray(shape)
    base = _MAX_SAMPLE_HALF + 1
    keys = (half[:, 0] * base + half[:, 1]) * base + half[:, 2]
    for key in np.unique(keys):
        sel = np.nonzero(keys == key)[0]
        h = half[sel[0]]
        grids = [np.linspace(-1.0, 1.0, 2 * int(n) + 1) if n > 0 else np.zeros(1) for n in h]
        u = np.stack(np.meshgrid(*grids, indexing="ij"), axis=-1).reshape(
            -1, 3
        )  # (S,3) in sigma units
        # chunk so that the (n, S, 3) point array stays below ~3M points
        step = max(1, 3_000_000 // len(u))
        for c0 in range(0, len(sel), step):
            idx = sel[c0 : c0 + step]
            local = u[None, :, :] * sig[idx, None, :]  # (n,S,3)
            pts = means[idx, None, :] + np.einsum("nij,nsj->nsi", axes[idx], local)
            cell = np.floor((pts.reshape(-1, 3) - origin) / dx).astype(np.int64)
            ok = ((cell >= 0) & (cell < dims)).all(axis=1)
            cell = cell[ok]
            occ[cell[:, 0], cell[:, 1], cell[:, 2]] = True
    return occ


def _classify(occ: np.ndarray, close: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``(interior, outside)`` cells of a box with occupied shell ``occ`` (bool, same shape).

    The shell is first thickened by ``close`` cells (6-connected dilation), which bridges
    gaps of up to ``2 * close`` cells between splats; the outside is the part of the free
    space 6-connected to the box border. That outside is then grown back through free
    cells by ``2 * close + 1`` steps (geodesic dilation), so the cells just outside the
    shell (staircase pits of a digital surface) count as outside again and no fill
    particle lands outside the object. Near a real gap the outside reaches in by at most
    those few cells. Interior = free and not outside. The box must leave ``close + 1``
    free cells around the shell.
    """
    from scipy import ndimage

    ball = ndimage.generate_binary_structure(3, 1)
    free = ~occ
    thick = ndimage.binary_dilation(occ, ball, iterations=close) if close > 0 else occ
    outside = ~ndimage.binary_fill_holes(thick, ball)
    if close > 0:
        outside = ndimage.binary_dilation(outside, ball, iterations=2 * close + 1, mask=free)
    return free & ~outside, outside


def _cell_weights(occ: np.ndarray, interior: np.ndarray, fill: bool) -> np.ndarray:
    """Fraction of each cell's volume dx^3 that belongs to the object, float64 (same shape).

    Occupied cells face-adjacent to a free cell (outside or interior) hold splat samples
    of a surface layer and are cut by the surface: 1/2 (on average half of a cut cell
    lies inside). Occupied cells surrounded by occupied cells (the body of a capture
    whose splats fill the object) count 1. Interior cells count 1 when ``fill`` (they
    get particles), else 0 (a hollow object).
    """
    from scipy import ndimage

    ball = ndimage.generate_binary_structure(3, 1)
    boundary = occ & ndimage.binary_dilation(~occ, ball, border_value=1)
    w = np.where(occ, 1.0, 0.0)
    w[boundary] = 0.5
    if fill:
        w[interior] = 1.0
    return w


def _particle_volumes(
    particles: np.ndarray, origin: np.ndarray, dx: float, weight: np.ndarray
) -> np.ndarray:
    """Rest volume of each particle [m^3], float64 (P,).

    Rule: the object is the voxelisation, cell (i,j,k) holding ``weight[i,j,k] * dx^3``
    (see :func:`_cell_weights`). Each cell's volume is shared equally by the particles
    inside it; a cell without particles gives its volume to the particle nearest its
    centre. So ``sum(volumes) = dx^3 * weight.sum()``.
    """
    from scipy.spatial import cKDTree

    shape = np.asarray(weight.shape)
    flat_w = weight.ravel() * dx**3
    cell = np.clip(np.floor((particles - origin) / dx).astype(np.int64), 0, shape - 1)
    flat = np.ravel_multi_index(cell.T, weight.shape)
    count = np.bincount(flat, minlength=flat_w.size)
    vol = flat_w[flat] / count[flat]
    orphan = np.nonzero((flat_w > 0) & (count == 0))[0]
    if orphan.size:
        centres = origin + (np.stack(np.unravel_index(orphan, weight.shape), axis=1) + 0.5) * dx
        _, nearest = cKDTree(particles).query(centres)
        np.add.at(vol, nearest, flat_w[orphan])
    return vol


# ---- 7. downsampling ---------------------------------------------------------------------------


def stratified_subset(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of ``k`` of the ``points (P,3)``, spread evenly in space.

    One random point per cube of the coarsest grid that still has at most ``k`` occupied
    cubes (bisection on the cube size), topped up with random others. Unlike a plain
    random subset, no region of the object (a beak, a thin tail) loses all its
    particles, so splats never follow a far-away particle.
    """
    from motionphysics.scene.mesh import _cell_keys

    p = len(points)
    if k >= p:
        return np.arange(p)
    order = rng.permutation(p)  # the first point of a cube in this order is a random one
    pts = points[order]
    ext = float((points.max(0) - points.min(0)).max()) or 1.0
    lo_h, hi_h = ext * 1e-6, ext * 2.0  # many cubes (> k, as k < p) ... one cube (<= k)
    best = None
    for _ in range(40):
        h = math.sqrt(lo_h * hi_h)
        _, first = np.unique(_cell_keys(pts, h), return_index=True)
        if len(first) <= k:
            hi_h, best = h, first
            if len(first) >= 0.98 * k:
                break
        else:
            lo_h = h
    if best is None:  # pragma: no cover - hi_h = 2 x extent always gives one cube
        best = np.zeros(1, dtype=np.int64)
    chosen = np.zeros(p, dtype=bool)
    chosen[best] = True
    rest = np.nonzero(~chosen)[0]
    chosen[rest[: k - len(best)]] = True  # rest is in random order already
    return np.sort(order[chosen])


# ---- the entry point -------------------------------------------------------------------------


def _select_splats(scene: GaussianScene, scene_cfg: SceneConfig, origin_name: str):
    """Steps 1-3: transform, opacity filter and crop, anisotropy regularisation.

    Returns (splats, source_to_world [4,4] float64 ndarray)."""
    splats, m, _static = _select(scene, scene_cfg, origin_name)
    return splats, m


def _select(scene: GaussianScene, scene_cfg: SceneConfig, origin_name: str):
    """:func:`_select_splats` and the static scene: ``(splats, source_to_world, static)``;
    ``static`` is the GaussianScene of the splats outside ``scene.region`` (inside
    ``crop``, any opacity, as transformed), or None without a region."""
    scene.validate(origin_name)
    splats, m = transform_scene(
        scene, scene_cfg.scale, scene_cfg.rotate, scene_cfg.translate, getattr(scene_cfg, "up", "z")
    )

    keep = splats.opacities >= scene_cfg.opacity_threshold
    n_opaque = int(keep.sum())
    cropped = torch.ones_like(keep)
    if scene_cfg.crop is not None:
        c = torch.tensor(scene_cfg.crop, dtype=splats.means.dtype)
        p = splats.means
        cropped = (
            (p[:, 0] >= c[0])
            & (p[:, 0] <= c[1])
            & (p[:, 1] >= c[2])
            & (p[:, 1] <= c[3])
            & (p[:, 2] >= c[4])
            & (p[:, 2] <= c[5])
        )
        keep &= cropped
    static = None
    region = getattr(scene_cfg, "region", None)
    if region is not None and bool(keep.any()):
        from motionphysics.scene.region import region_mask, region_text

        inside = torch.from_numpy(region_mask(splats.means.double().numpy(), region))
        if not bool((keep & inside).any()):
            lo = splats.means[keep].min(0).values.tolist()
            hi = splats.means[keep].max(0).values.tolist()
            raise UserInputError(
                f"{origin_name}: scene.region {region_text(region)} holds none of the "
                f"{int(keep.sum())} splats kept (they span {np.round(lo, 3).tolist()} to "
                f"{np.round(hi, 3).tolist()} m after the scene transform); move or widen it"
            )
        static = splats.subset(torch.nonzero(cropped & ~inside).flatten())
        keep &= inside
    if not bool(keep.any()):
        where = (
            f"scene.opacity_threshold={scene_cfg.opacity_threshold} kept {n_opaque} of {splats.num}"
            + (
                f" and scene.crop={list(scene_cfg.crop)} kept none of them"
                if scene_cfg.crop
                else ""
            )
        )
        raise UserInputError(
            f"{origin_name}: no splats left to simulate ({where}); lower the threshold or widen the crop"
        )
    return regularise_anisotropy(splats.subset(keep), scene_cfg.max_anisotropy), m, static


def selected_means(scene: GaussianScene, scene_cfg: SceneConfig) -> np.ndarray:
    """World-frame centres [N, 3] m (float64) of the splats :func:`prepare` simulates
    (steps 1-3: transform, opacity filter, crop): the visible particles' positions."""
    splats, _ = _select_splats(scene, scene_cfg, scene_cfg.source)
    return splats.means.double().numpy()


def _fallback_extent(splats: GaussianScene) -> float:
    big = float(splats.scales.max())
    return max(4.0 * big, 1e-3) if math.isfinite(big) else 1e-3


def _particles_at(splats: GaussianScene, scene_cfg: SceneConfig, lo: np.ndarray, dx: float):
    """Steps 5-7 on the grid (``lo``, ``dx``): voxelise, fill, volumes, downsample.

    Returns (particles [P,3] float64, volumes [P], n_interior, splat_parent [N] int,
    total_volume); particles are visible-derived first, then interior fill."""
    vis = splats.means.double().numpy()  # (N,3)
    # Voxel box: cells aligned with the domain's grid around the particles, with a free
    # margin so that the outside is connected around the object (it may poke out of the
    # domain: only the interior, which lies within the particles' hull, is used).
    margin = 2 + _CLOSE_CELLS + _MAX_SAMPLE_HALF  # splat samples may reach 4 dx past a mean
    c_lo = np.floor((vis.min(0) - lo) / dx).astype(np.int64) - margin
    c_hi = np.floor((vis.max(0) - lo) / dx).astype(np.int64) + 1 + margin
    vox_origin = lo + c_lo * dx
    shape = tuple(int(v) for v in (c_hi - c_lo))
    shell = voxelise(splats, vox_origin, dx, shape)
    inner, _ = _classify(shell, _CLOSE_CELLS)
    # A capture whose splats fill the object (many trained 3DGS scenes put splats through
    # the volume) has no free enclosed cell: its inside is occupied. The occupied cells
    # away from its surface that hold no splat centre get fill particles too.
    gaps, body = _body_gaps(shell, vis, vox_origin, dx)
    wanted = inner | gaps
    interior_cells = np.argwhere(wanted) if scene_cfg.fill else np.zeros((0, 3), np.int64)
    n_wanted = len(interior_cells)
    if len(interior_cells) > scene_cfg.max_particles:
        # Clear cap: never more interior candidates than max_particles (an even subset;
        # the skipped cells' volume goes to the nearest particle, so mass is kept).
        pick = stratified_subset(
            interior_cells.astype(np.float64),
            scene_cfg.max_particles,
            np.random.default_rng(FILL_SEED),
        )
        interior_cells = interior_cells[pick]
    fill_pts = vox_origin + (interior_cells + 0.5) * dx
    particles = np.concatenate([vis, fill_pts])
    weight = _cell_weights(shell, inner, scene_cfg.fill)
    volumes = _particle_volumes(particles, vox_origin, dx, weight)
    total_volume = float(volumes.sum())
    n_vis, n_int = len(vis), len(fill_pts)

    parent = np.arange(n_vis)
    if len(particles) > scene_cfg.max_particles:
        from scipy.spatial import cKDTree

        kept = stratified_subset(
            particles, scene_cfg.max_particles, np.random.default_rng(FILL_SEED + 1)
        )
        tree = cKDTree(particles[kept])
        is_kept = np.zeros(len(particles), dtype=bool)
        is_kept[kept] = True
        new_volumes = volumes[kept].copy()
        dropped = np.nonzero(~is_kept)[0]
        _, near = tree.query(particles[dropped])
        np.add.at(new_volumes, near, volumes[dropped])  # mass is conserved
        new_index = np.full(len(particles), -1)
        new_index[kept] = np.arange(len(kept))
        parent = new_index[:n_vis].copy()
        lost = parent < 0
        parent[lost] = near[np.searchsorted(dropped, np.nonzero(lost)[0])]
        particles, volumes = particles[kept], new_volumes
        n_int = int((kept >= n_vis).sum())
    note, hollow = None, False
    if scene_cfg.fill and n_int == 0:
        note, hollow = _fill_note(n_wanted, int(body.sum()), dx, scene_cfg.max_particles)
    return particles, volumes, int(n_int), parent, total_volume, (note, hollow)


def _body_gaps(
    occ: np.ndarray, centres: np.ndarray, origin: np.ndarray, dx: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(gaps, body)`` bool (same shape as ``occ``): ``body`` = occupied cells at least
    two cells (6-connected steps) inside the occupied region (the inside of a capture
    whose splats fill the object; the one or two cell thick layer that splats on a
    surface occupy, edges and corners included, has none), ``gaps`` = those of them
    holding no splat centre (``centres`` [N, 3] m)."""
    from scipy import ndimage

    ball = ndimage.generate_binary_structure(3, 1)
    body = ndimage.binary_erosion(occ, ball, iterations=2, border_value=0)
    cell = np.floor((centres - origin) / dx).astype(np.int64)
    ok = ((cell >= 0) & (cell < np.asarray(occ.shape))).all(axis=1)
    held = np.zeros(occ.shape, dtype=bool)
    held[tuple(cell[ok].T)] = True
    return body & ~held, body


def _fill_note(n_wanted: int, n_body: int, dx: float, max_particles: int) -> tuple[str, bool]:
    """Why ``fill: true`` gave no interior particle, with the consequence: ``(line,
    hollow)``; ``hollow`` when the object is simulated as a shell (no enclosed cell)."""
    if n_wanted > 0:
        return (
            f"fill: the {n_wanted} interior particles were all dropped by scene.max_particles"
            f" = {max_particles}; the nearest kept particles carry their mass",
            False,
        )
    if n_body > 0:
        return (
            f"fill: nothing to add: the capture's splats already fill its inside (all "
            f"{n_body} inner cells at dx = {dx:.3g} m hold a splat centre); simulated solid",
            False,
        )
    return (
        f"fill: no interior particles: at dx = {dx:.3g} m the splats enclose no cell (the "
        "surface is open, has gaps wider than 2 cells, or is thinner than 3 cells at this "
        "grid); the object is simulated hollow, with the mass of its surface layer only "
        "(a finer sim.grid or a closed mesh fills it)",
        True,
    )


def prepare(
    scene: GaussianScene,
    scene_cfg: SceneConfig,
    sim_cfg: SimConfig,
    boundary_conditions: list | tuple = (),
    forces: list | tuple = (),
    material_class: str | None = None,
) -> SimScene:
    """Transform, filter and regularise ``scene``; fill it, size the grid, downsample.

    See the module docstring for the order. Raises UserInputError when nothing is left
    after the opacity filter and crop, or when a given ``sim.domain`` does not hold the
    particles. A fitted domain leaves room for the motion the config implies
    (:func:`motion_extent`: ``sim`` initial velocity and gravity over the simulated time,
    ``forces``, and the spread of a ``material_class`` fluid or sand).
    """
    splats, m, static = _select(scene, scene_cfg, scene_cfg.source)
    vis = splats.means.double().numpy()  # (N,3)
    fallback = _fallback_extent(splats)
    if sim_cfg.domain is not None:
        dx, wall_lo, wall_hi = _given_domain(vis, sim_cfg.domain, sim_cfg.grid)
        keep_dims = None
    else:
        # the static scene of a region holds the object up: its fall stops there, as on a
        # floor (else the domain would grow for a fall through the whole simulated time)
        planes = list(boundary_conditions) + _static_floor(static, [scene_cfg], vis, sim_cfg)
        motion = motion_extent(
            sim_cfg,
            forces,
            planes,
            material_class,
            height=_height(vis, sim_cfg.gravity),
        )
        lo, dx, keep_dims, hi = fit_domain(
            vis, sim_cfg.grid, planes, fallback_extent=fallback, motion=motion
        )
        # the material box: the fitted box without the solver's padding cells
        wall_lo, wall_hi = lo + PAD_CELLS * dx, hi - PAD_CELLS * dx
    targets = _wall_targets(wall_lo, wall_hi, boundary_conditions)
    lo, dims, hi, wall_hi = _aligned_grid(wall_lo, wall_hi, dx, targets, keep_dims)

    particles, volumes, n_int, parent, total_volume, (note, hollow) = _particles_at(
        splats, scene_cfg, lo, dx
    )
    offset = vis - particles[parent]
    collider, note_static = _static_parts(
        static, [scene_cfg], lo, dx, dims, particles, sim_cfg, source_to_world=m
    )

    return SimScene(
        splats=splats,
        particles=torch.from_numpy(particles).float(),
        volumes=torch.from_numpy(volumes).float(),
        n_interior=int(n_int),
        splat_parent=torch.from_numpy(parent.astype(np.int64)),
        splat_offset=torch.from_numpy(offset).float(),
        domain_lo=torch.from_numpy(lo).float(),
        domain_hi=torch.from_numpy(hi).float(),
        dx=float(dx),
        grid_dims=tuple(int(d) for d in dims),
        source_to_world=torch.from_numpy(m),
        total_volume=total_volume,
        wall_lo=torch.from_numpy(np.asarray(wall_lo, dtype=np.float64)).float(),
        wall_hi=torch.from_numpy(np.asarray(wall_hi, dtype=np.float64)).float(),
        fill_note=note,
        fill_hollow=hollow,
        static_splats=static,
        static_collider=collider,
        static_note=note_static,
    )


def widen_for_spread(sim_scene: SimScene, material_class: str | None, sim_cfg, scene_cfg):
    """``(sim_scene, note)``: a fitted domain widened across gravity, at the same ``dx``,
    so that a liquid, a paste or sand has room to spread (:data:`FLUID_SPREAD` object
    heights per side, less the room the fit already left); ``note`` is the summary's line
    (None, and the scene unchanged, when nothing is added).

    The material class is known only after the estimate, when the domain is already
    fitted; growing the fitted box instead (``motion_extent`` with the class) coarsened the
    grid (a sand column's dx 0.031 -> 0.085 m, five cells across it). Whole cells are
    added on each side, so every particle keeps its place relative to the nodes, the
    collider planes stay half-way between nodes, and the grid the solver touches (the
    particles' region) is the same: only the walls move out. Before, a water ball that
    splashed hit a wall at half its run-out and sloshed back, which a viewer sees as an
    invisible wall. Not with a given ``sim.domain``, a ``scene.region`` (the static
    scene's collider lives on the grid), or without gravity."""
    spread = FLUID_SPREAD.get(material_class or "", 0.0)
    g = np.asarray(sim_cfg.gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    if (
        spread <= 0
        or sim_cfg.domain is not None
        or getattr(scene_cfg, "region", None) is not None
        or not gn > 0
        or sim_scene.wall_lo is None
    ):
        return sim_scene, None
    p = sim_scene.particles.double().numpy()
    dx = float(sim_scene.dx)
    room = spread * _height(p, g)
    side = np.sqrt(np.clip(1.0 - (g / gn) ** 2, 0.0, 1.0))  # weight of each axis across gravity
    wall_lo = sim_scene.wall_lo.double().numpy()
    wall_hi = sim_scene.wall_hi.double().numpy()
    have = np.minimum(p.min(0) - wall_lo, wall_hi - p.max(0))
    add = np.where(side > 0.5, np.ceil(np.maximum(room * side - have, 0.0) / dx), 0.0)
    add = add.astype(np.int64)
    if not add.any():
        return sim_scene, None
    shift = torch.from_numpy(add * dx).float()
    dims = tuple(int(d + 2 * a) for d, a in zip(sim_scene.grid_dims, add, strict=True))
    lo = sim_scene.domain_lo.double() - torch.from_numpy(add * dx)
    out = replace(
        sim_scene,
        domain_lo=lo.float(),
        domain_hi=(lo + torch.from_numpy((np.asarray(dims) - 1) * dx)).float(),
        grid_dims=dims,
        wall_lo=sim_scene.wall_lo - shift,
        wall_hi=sim_scene.wall_hi + shift,
    )
    cells = int(add.max())
    note = (
        f"domain: {cells} cells ({cells * dx:.3g} m) added on each side across gravity at "
        f"the same dx ({dx:.3g} m), room for the {material_class} to spread "
        f"({spread:g} object heights); `sim.domain` sets the box yourself"
    )
    return out, note


def _static_floor(static, cfgs, points, sim_cfg) -> list[dict]:
    """For sizing the domain only: the static scene of a region (colliding) as a floor
    plane under ``points`` [N, 3] m, facing against gravity; [] otherwise."""
    if static is None or all(getattr(c, "static_collider", "off") == "off" for c in cfgs):
        return []
    g = np.asarray(sim_cfg.gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    if not gn > 0:
        return []
    up = -g / gn
    low = points[int(np.argmin(points @ up))]
    return [
        {
            "type": "surface_collider",
            "mode": "frictional",
            "point": tuple(float(v) for v in low),
            "normal": tuple(float(v) for v in up),
        }
    ]


def _static_parts(static, cfgs, lo, dx, dims, particles, sim_cfg, source_to_world=None):
    """``(collider, note)`` of the static scene ``static`` (None: no region) on the grid
    (node 0 at ``lo``, spacing ``dx``, ``dims`` nodes): the level set of
    :func:`motionphysics.scene.region.static_collider` under the collider keys of the
    configs with a region (which must agree), and the one-line support note."""
    if static is None:
        return None, None
    from motionphysics.scene.region import static_collider, support_note, tilt_note

    with_region = [c for c in cfgs if getattr(c, "region", None) is not None]
    modes = {(c.static_collider, float(c.static_friction)) for c in with_region}
    if len(modes) > 1:
        raise UserInputError(
            "objects: the entries with a region disagree on static_collider / "
            "static_friction (one static scene holds them all); give the same values"
        )
    mode, friction = modes.pop()
    tilt = None if source_to_world is None else tilt_note(static, particles, source_to_world)
    if mode == "off":
        return None, tilt
    threshold = min(float(c.opacity_threshold) for c in with_region)
    collider = static_collider(
        static, threshold, lo, dx, dims, mode, friction, particles, sim_cfg.gravity
    )
    notes = [support_note(collider, particles, dx, sim_cfg.gravity), tilt]
    if collider is not None:
        deep = int((collider.sample(particles) < -dx).sum())
        if deep > 0.01 * len(particles):
            notes.append(
                f"static scene: {deep} of the {len(particles)} simulated particles start more "
                "than a cell inside the static splats (scene.region cuts through them); the "
                "first substep pushes them out onto its surface"
            )
    return collider, "; ".join(n for n in notes if n) or None


def _grown_box(points, sim_cfg, forces, boundary_conditions, material_class, velocity, fallback):
    """The box [lo (3,), hi (3,)] of ``points`` grown by the motion one object may make
    (:func:`motion_extent` with its own initial ``velocity``; capped at ``MOTION_CAP``
    extents per side and stopped at the axis-aligned collider planes it faces), as
    :func:`fit_domain` grows a single object's box."""
    own = sim_cfg.model_copy(update={"initial_velocity": tuple(float(v) for v in velocity)})
    down, up = motion_extent(
        own, forces, boundary_conditions, material_class, height=_height(points, sim_cfg.gravity)
    )
    lo, hi = points.min(0).astype(np.float64), points.max(0).astype(np.float64)
    ext = float((hi - lo).max())
    if not ext >= 1e-6 * max(fallback, float(np.abs(points).max())):
        ext = fallback
    grown_lo = lo + np.maximum(down, -MOTION_CAP * ext)
    grown_hi = hi + np.minimum(up, MOTION_CAP * ext)
    return _stop_at_planes(lo, hi, grown_lo, grown_hi, boundary_conditions)


def _stop_at_planes(lo, hi, grown_lo, grown_hi, boundary_conditions):
    """``grown_lo``/``grown_hi`` (the box ``lo``/``hi`` grown by its motion), stopped at
    the axis-aligned non-cut collider planes the box faces (motion ends there)."""
    for bc in boundary_conditions:
        if _get(bc, "type") != "surface_collider" or _get(bc, "mode") == "cut":
            continue
        n = np.asarray(_get(bc, "normal", (0.0, 0.0, 1.0)), dtype=np.float64)
        p = np.asarray(_get(bc, "point", (0.0, 0.0, 0.0)), dtype=np.float64)
        nn = float(np.linalg.norm(n))
        if not nn > 0:
            continue
        a = int(np.argmax(np.abs(n)))
        if abs(abs(n[a]) / nn - 1.0) > 1e-9:
            continue
        if n[a] > 0 and p[a] <= lo[a]:
            grown_lo[a] = max(grown_lo[a], p[a])
        elif n[a] < 0 and p[a] >= hi[a]:
            grown_hi[a] = min(grown_hi[a], p[a])
    return grown_lo, grown_hi


OVERLAP = 0.5
"""Two objects start one inside the other when at least this fraction of the smaller
one's box lies in the other's box and at least this fraction of its particles lie in grid
cells holding the other's particles: the run stops with one line."""


def object_overlap(particles, object_id, dx: float, names) -> str | None:
    """One line for the first pair of objects that start inside each other (None: no
    such pair). Two objects written without ``translate`` both sit at the origin, and a
    run of them shows one object (two superimposed, falling as one) or two flung apart by
    the contact. Both measures must say so (:data:`OVERLAP`): the boxes, so that objects
    that merely touch at this grid's coarse cells (two 3.5-cell balls side by side share
    a fifth of their cells) pass, and the cells, so that a ball inside a bowl (one box in
    the other, the ball in the bowl's empty middle) passes."""
    p = np.asarray(particles, dtype=np.float64)
    oid = np.asarray(object_id).astype(np.int64)
    cells = np.floor(p / float(dx)).astype(np.int64)
    keys = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791)
    parts = [oid == i for i in range(len(names))]
    boxes = [(p[m].min(0), p[m].max(0)) if m.any() else None for m in parts]
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if boxes[i] is None or boxes[j] is None:
                continue
            small, other = (j, i) if parts[j].sum() <= parts[i].sum() else (i, j)
            (slo, shi), (olo, ohi) = boxes[small], boxes[other]
            vol = float(np.prod(np.maximum(shi - slo, dx)))
            common = float(np.prod(np.maximum(np.minimum(shi, ohi) - np.maximum(slo, olo), 0)))
            if common < OVERLAP * vol:
                continue
            frac = float(np.isin(keys[parts[small]], np.unique(keys[parts[other]])).mean())
            if frac >= OVERLAP:
                return (
                    f"objects: {names[small]} and {names[other]} start inside each other "
                    f"({100 * frac:.0f} % of {names[small]}'s particles lie in "
                    f"{names[other]}'s grid cells, {100 * common / vol:.0f} % of its box in "
                    f"{names[other]}'s); give each its own place with `translate` (objects "
                    "written without one all sit at the origin)"
                )
    return None


def prepare_objects(
    scenes: list[GaussianScene],
    object_cfgs: list,
    sim_cfg: SimConfig,
    boundary_conditions: list | tuple = (),
    forces: list | tuple = (),
    material_classes: list | None = None,
) -> SimScene:
    """Several objects (``config.ObjectConfig`` each, with its loaded scene) -> one SimScene.

    Each object is transformed, filtered and cropped with its own scene keys; the domain
    is the given ``sim.domain`` or fitted around all objects, each grown by its own
    motion (initial velocity ``object.initial_velocity`` or ``sim.initial_velocity``),
    then by 0.5 x the extent of the union; every object is voxelised, filled and
    downsampled (``max_particles`` is its share) on that one grid. Particles are
    ordered visible-derived first (object 0, 1, ...), then the interior fill (object 0,
    1, ...), so ``n_visible`` keeps its meaning; ``object_id [P]`` says whose each one
    is; ``splats`` are the objects' splats concatenated in object order.
    ``source_to_world`` is object 0's transform.
    """
    if len(scenes) != len(object_cfgs) or not scenes:
        raise ValueError("prepare_objects: one loaded scene per object config")
    classes = list(material_classes or [None] * len(scenes))
    picked, statics = [], {}
    for scene, ocfg in zip(scenes, object_cfgs, strict=True):
        sp, m, static = _select(scene, ocfg, f"objects[{ocfg.name}] {ocfg.source}")
        picked.append((sp, m))
        if static is not None:
            # objects cut from one capture (the same scene and transform) share its
            # static scene: the splats outside every one of their regions
            key = (id(scene), _transform_key(ocfg))
            inside = statics.get(key, (scene, ocfg, []))[2]
            inside.append(ocfg.region)
            statics[key] = (scene, ocfg, inside)
    vis_all = np.concatenate([sp.means.double().numpy() for sp, _ in picked])
    if sim_cfg.domain is not None:
        dx, wall_lo, wall_hi = _given_domain(vis_all, sim_cfg.domain, sim_cfg.grid)
        keep_dims = None
    else:
        boxes = []
        for (sp, _), ocfg, cls in zip(picked, object_cfgs, classes, strict=True):
            v = (
                ocfg.initial_velocity
                if ocfg.initial_velocity is not None
                else sim_cfg.initial_velocity
            )
            pts = sp.means.double().numpy()
            boxes.append(
                _grown_box(pts, sim_cfg, forces, boundary_conditions, cls, v, _fallback_extent(sp))
            )
        blo = np.min([b[0] for b in boxes], axis=0)
        bhi = np.max([b[1] for b in boxes], axis=0)
        corners = np.array(
            [
                [x, y, z]
                for x in (blo[0], bhi[0])
                for y in (blo[1], bhi[1])
                for z in (blo[2], bhi[2])
            ]
        )
        lo, dx, keep_dims, hi = fit_domain(
            corners,
            sim_cfg.grid,
            boundary_conditions,
            fallback_extent=max(_fallback_extent(sp) for sp, _ in picked),
        )
        wall_lo, wall_hi = lo + PAD_CELLS * dx, hi - PAD_CELLS * dx
    targets = _wall_targets(wall_lo, wall_hi, boundary_conditions)
    lo, dims, hi, wall_hi = _aligned_grid(wall_lo, wall_hi, dx, targets, keep_dims)

    parts = [
        _particles_at(sp, ocfg, lo, dx) for (sp, _), ocfg in zip(picked, object_cfgs, strict=True)
    ]
    static = _shared_static(statics)
    n_vis = [len(p[0]) - p[2] for p in parts]
    n_int = [p[2] for p in parts]
    vis_start = np.concatenate([[0], np.cumsum(n_vis)])
    int_start = int(vis_start[-1]) + np.concatenate([[0], np.cumsum(n_int)])
    particles, volumes, oid, parents, offsets = [], [], [], [], []
    order_vis, order_int = [], []
    for k, ((sp, _), (pts, vol, ni, parent, _tv, _n)) in enumerate(zip(picked, parts, strict=True)):
        nv = len(pts) - ni
        order_vis.append((pts[:nv], vol[:nv], k))
        order_int.append((pts[nv:], vol[nv:], k))
        # the particle a splat follows, in the scene's order
        local = np.asarray(parent)
        glob = np.where(local < nv, vis_start[k] + local, int_start[k] + (local - nv))
        parents.append(glob)
        offsets.append(sp.means.double().numpy() - pts[local])
    for pts, vol, k in order_vis + order_int:
        particles.append(pts)
        volumes.append(vol)
        oid.append(np.full(len(pts), k, dtype=np.int64))
    splats = GaussianScene.concat([sp for sp, _ in picked])
    return SimScene(
        splats=splats,
        particles=torch.from_numpy(np.concatenate(particles)).float(),
        volumes=torch.from_numpy(np.concatenate(volumes)).float(),
        n_interior=int(sum(n_int)),
        splat_parent=torch.from_numpy(np.concatenate(parents).astype(np.int64)),
        splat_offset=torch.from_numpy(np.concatenate(offsets)).float(),
        domain_lo=torch.from_numpy(lo).float(),
        domain_hi=torch.from_numpy(hi).float(),
        dx=float(dx),
        grid_dims=tuple(int(d) for d in dims),
        source_to_world=torch.from_numpy(picked[0][1]),
        total_volume=float(sum(p[4] for p in parts)),
        wall_lo=torch.from_numpy(np.asarray(wall_lo, dtype=np.float64)).float(),
        wall_hi=torch.from_numpy(np.asarray(wall_hi, dtype=np.float64)).float(),
        object_id=torch.from_numpy(np.concatenate(oid)),
        fill_note="; ".join(
            f"{o.name}: {p[5][0]}" for o, p in zip(object_cfgs, parts, strict=True) if p[5][0]
        )
        or None,
        fill_hollow=any(p[5][1] for p in parts),
        static_splats=static,
        **dict(
            zip(
                ("static_collider", "static_note"),
                _static_parts(
                    static,
                    object_cfgs,
                    lo,
                    dx,
                    dims,
                    np.concatenate(particles),
                    sim_cfg,
                    picked[0][1],
                ),
                strict=True,
            )
        ),
    )


def _transform_key(ocfg) -> tuple:
    """What places a capture's splats in the world (objects with equal keys share them)."""
    return (
        str(ocfg.up),
        float(ocfg.scale),
        tuple(tuple(r) for r in ocfg.rotate),
        tuple(ocfg.translate),
        None if ocfg.crop is None else tuple(ocfg.crop),
    )


def _shared_static(statics: dict) -> GaussianScene | None:
    """The static scene of objects with regions: per capture (scene and transform), its
    splats outside all of their regions (inside ``crop``, any opacity); captures
    concatenated in the order of their first object. None when no object has a region."""
    if not statics:
        return None
    from motionphysics.scene.region import region_mask

    out = []
    for scene, ocfg, regions in statics.values():
        splats, _ = transform_scene(scene, ocfg.scale, ocfg.rotate, ocfg.translate, ocfg.up)
        p = splats.means.double().numpy()
        keep = np.ones(len(p), dtype=bool)
        if ocfg.crop is not None:
            c = ocfg.crop
            keep &= (
                (p[:, 0] >= c[0])
                & (p[:, 0] <= c[1])
                & (p[:, 1] >= c[2])
                & (p[:, 1] <= c[3])
                & (p[:, 2] >= c[4])
                & (p[:, 2] <= c[5])
            )
        for region in regions:
            keep &= ~region_mask(p, region)
        out.append(splats.subset(torch.from_numpy(np.nonzero(keep)[0])))
    return GaussianScene.concat(out) if len(out) > 1 else out[0]
