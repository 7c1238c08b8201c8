"""A region of a capture is simulated; the rest stays, is drawn, and holds it up.

Three pieces, used by :mod:`motionphysics.scene.prepare`:

* :func:`up_rotation` -- ``scene.up`` (the capture's vertical axis, ``y`` for Brush and
  many nerfstudio exports, or a vector) as the shortest rotation that takes it to +z.
* :func:`region_mask` -- which splat centres lie inside ``scene.region`` (a box or a
  sphere in the world frame, the selectors forces use).
* :func:`static_collider` -- the static splats near the simulated region as a fixed
  collider: a signed-distance level set of the cells they occupy, sampled on cells of
  half the simulation grid's spacing (:class:`StaticCollider`), which the boundary
  program (``sim.boundary``) applies to the grid nodes inside it (frictional, sticky or
  slip, zero velocity of its own) and onto which it projects particles that reach
  behind its surface (as it does for collider planes). :func:`support_note` says in
  one line when the static scene under the simulated splats is too sparse to hold them.

Resolution (what a person should know; docs/capture.md): the level set's cells are
``h = dx / 4`` (``LEVELSET_REFINE``; coarser on large grids); a splat marks the cells its one-sigma box reaches, sigma
capped at one cell (``prepare.voxelise``), so the surface lies between the highest splat
centre and ``2 h`` above it. Gaps up to ``CLOSE_GAP`` dx across z between static cells
are closed, and near the simulated splats' lowest point the support under them (which
no view of a capture sees) is filled and its gaps up to ``SUPPORT_GAP`` dx are closed;
wider holes stay holes material can fall through. Features thinner than a cell still
stop material (the particle projection acts at any depth), but their normal is only as
good as a finite difference at ``h``. Nothing here simulates or renders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from motionphysics.errors import UserInputError

__all__ = [
    "StaticCollider",
    "region_mask",
    "region_text",
    "static_collider",
    "support_note",
    "up_rotation",
    "LEVELSET_REFINE",
    "MIN_COMPONENT_CELLS",
    "SUPPORT_FRACTION",
]

LEVELSET_REFINE = 4
"""The level set's cells are ``dx / LEVELSET_REFINE`` (the simulation grid's spacing dx),
or coarser (``dx / 2``, ``dx``) when that would exceed :data:`LEVELSET_MAX_CELLS`."""
LEVELSET_MAX_CELLS = 16_000_000
"""Most level-set samples (a grid of 64 cells refines 4x; a grid of 128, 2x)."""
MIN_COMPONENT_CELLS = 4
"""Occupied clusters of fewer level-set cells than this (26-connected) are floaters
(isolated stray splats of a capture) and do not collide."""
SUPPORT_FRACTION = 0.5
"""Below this fraction of the simulated splats' footprint covered by static splats
underneath (columns of dx), the run says the static scene is too sparse to hold it."""

_AXES = {
    "x": (1.0, 0.0, 0.0),
    "y": (0.0, 1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
}


def up_vector(up) -> np.ndarray:
    """``scene.up`` (``z``, ``-y``, ..., or ``[ux, uy, uz]``) as a unit vector (3,) float64."""
    if isinstance(up, str):
        sign = -1.0 if up.startswith("-") else 1.0
        try:
            return sign * np.asarray(_AXES[up.lstrip("-+")], dtype=np.float64)
        except KeyError:
            raise UserInputError(
                f"scene.up: expected z, y, x, -z, -y, -x or [ux, uy, uz], got {up!r}"
            ) from None
    u = np.asarray(up, dtype=np.float64).reshape(-1)
    n = float(np.linalg.norm(u)) if u.shape == (3,) else 0.0
    if not n > 0 or not math.isfinite(n):
        raise UserInputError(f"scene.up: expected a non-zero vector [ux, uy, uz], got {list(u)}")
    return u / n


def up_rotation(up) -> np.ndarray:
    """The shortest rotation (3, 3) float64 taking ``scene.up`` to +z (identity for ``z``).

    ``y`` -> a quarter turn about +x (y to z, z to -y); ``-z`` -> a half turn about +x.
    """
    u = up_vector(up)
    z = np.array([0.0, 0.0, 1.0])
    c = float(u @ z)
    if c > 1.0 - 1e-15:
        return np.eye(3)
    if c < -1.0 + 1e-15:
        return np.diag([1.0, -1.0, -1.0])  # half turn about x
    axis = np.cross(u, z)
    s = float(np.linalg.norm(axis))
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    # Rodrigues, with the exact quarter turns of the axis names (no 6e-17 residue)
    r = np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)
    return r


def region_mask(points: np.ndarray, region) -> np.ndarray:
    """Bool [N]: which ``points`` [N, 3] m lie inside ``region`` (``config.Region``: a box
    ``[[x0, y0, z0], [x1, y1, z1]]`` or a sphere ``[[x, y, z], r]``, boundary included)."""
    p = np.asarray(points, dtype=np.float64)
    if region.box is not None:
        lo = np.asarray(region.box[0], dtype=np.float64)
        hi = np.asarray(region.box[1], dtype=np.float64)
        return ((p >= lo) & (p <= hi)).all(axis=1)
    c = np.asarray(region.sphere[0], dtype=np.float64)
    r = float(region.sphere[1])
    return ((p - c) ** 2).sum(axis=1) <= r * r


def region_text(region) -> str:
    """The region as a config person wrote it (for messages)."""
    if region.box is not None:
        return f"{{box: {[list(region.box[0]), list(region.box[1])]}}}"
    return f"{{sphere: {[list(region.sphere[0]), region.sphere[1]]}}}"


@dataclass(frozen=True)
class StaticCollider:
    """The static scene as a fixed collider: a signed-distance level set.

    ``phi[i, j, k]`` is the signed distance [m] (negative inside the cells the static
    splats occupy) at the point ``lo + (i, j, k) * h``; ``normal`` its unit gradient
    (outward, towards free space). Both are sampled trilinearly by the kernels
    (``sim.boundary_kernels._static_grid`` / ``_project_levelset``).
    """

    phi: np.ndarray
    """Signed distance [m], shape (nx, ny, nz), float32."""
    normal: np.ndarray
    """Unit outward normal [-], shape (nx, ny, nz, 3), float32."""
    lo: np.ndarray
    """Position of sample (0, 0, 0) [m], shape (3,), float64."""
    h: float
    """Sample spacing [m] (``dx / LEVELSET_REFINE``)."""
    mode: str
    """``frictional`` | ``sticky`` | ``slip``."""
    friction: float
    """Coulomb coefficient of the frictional mode [-]."""
    splats: int
    """How many static splats occupy its cells (after the opacity filter)."""
    cells: int
    """How many of its cells are occupied."""
    filled: int = 0
    """Columns of unseen support filled under the simulated splats (:func:`_fill_support`)."""
    fill_height: float | None = None
    """Height [m] of the filled support's top (the static support around it), or None."""
    closed: int = 0
    """Columns of gaps in the support (up to :data:`SUPPORT_GAP` dx wide) closed
    (:func:`_close_support`)."""

    def sample(self, points: np.ndarray) -> np.ndarray:
        """phi [m] at ``points`` [N, 3] (trilinear, clamped at the edges), float64 [N]."""
        from scipy import ndimage

        g = (np.asarray(points, dtype=np.float64) - self.lo) / self.h
        return ndimage.map_coordinates(self.phi.astype(np.float64), g.T, order=1, mode="nearest")


def static_collider(
    static,
    opacity_threshold: float,
    grid_lo: np.ndarray,
    dx: float,
    grid_dims,
    mode: str,
    friction: float,
    simulated: np.ndarray | None = None,
    gravity=(0.0, 0.0, -9.8),
) -> StaticCollider | None:
    """The level set of the static splats (a :class:`GaussianScene`, world frame) over the
    simulation grid (node 0 at ``grid_lo`` [m], spacing ``dx``, ``grid_dims`` nodes).

    Splats below ``opacity_threshold`` and clusters of fewer than
    :data:`MIN_COMPONENT_CELLS` cells (floaters) do not collide. ``simulated`` [P, 3] m
    (the simulated particles at rest) and a gravity along -z: the support the capture
    cannot see (under the simulated splats, where they stood) is filled
    (:func:`_fill_support`). Returns None when no static splat occupies a cell of the grid.
    """
    from scipy import ndimage

    from motionphysics.scene.prepare import voxelise

    nodes = float(np.prod(np.asarray(grid_dims, dtype=np.float64)))
    refine = LEVELSET_REFINE
    while refine > 1 and nodes * refine**3 > LEVELSET_MAX_CELLS:
        refine //= 2
    h = float(dx) / refine
    lo = np.asarray(grid_lo, dtype=np.float64)
    hi = lo + (np.asarray(grid_dims) - 1) * float(dx)
    shape = tuple(int(math.ceil((b - a) / h - 1e-9)) + 1 for a, b in zip(lo, hi, strict=True))
    origin = lo - 0.5 * h  # sample (i, j, k) = the centre of cell (i, j, k)
    keep = (static.opacities >= opacity_threshold).numpy()
    means = static.means.double().numpy()
    margin = 4.0 * dx  # a splat's samples reach at most 4 h past its centre
    near = keep & ((means >= lo - margin) & (means <= hi + margin)).all(axis=1)
    if not near.any():
        return None
    # each splat marks the cells of its one-sigma box, sigma capped at one cell: a surface
    # of overlapping splats stays closed and is thickened by at most one cell
    near_splats = static.subset(np.nonzero(near)[0])
    near_splats.log_scales = near_splats.log_scales.clamp(max=math.log(h))
    occ = voxelise(near_splats, origin, h, shape)
    # a capture's surfaces are sparse (a table of scattered splats): gaps up to
    # CLOSE_GAP dx wide across gravity's axis (z) are bridged (a closing by a flat disk)
    r = max(1, int(round(CLOSE_GAP * refine / 2)))
    disk = np.zeros((2 * r + 1, 2 * r + 1, 3), dtype=bool)
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disk[:, :, 1] = xx**2 + yy**2 <= r * r
    disk[r, r, :] = True
    occ = ndimage.binary_closing(np.pad(occ, r + 1), disk)[
        r + 1 : -r - 1, r + 1 : -r - 1, r + 1 : -r - 1
    ]
    labels, n = ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))
    if n:
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        small = sizes < MIN_COMPONENT_CELLS
        small[0] = False
        occ &= ~small[labels]
    if not occ.any():
        return None
    filled, fill_height, closed = 0, None, 0
    g = np.asarray(gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    if simulated is not None and gn > 0 and g[2] / gn < -0.99:
        pts = np.asarray(simulated, np.float64)
        filled, fill_height = _fill_support(occ, origin, h, pts, refine)
        closed = _close_support(occ, origin, h, pts, refine)
    outside = ndimage.distance_transform_edt(~occ) * h  # free samples: to the nearest occupied
    inside = ndimage.distance_transform_edt(occ) * h  # occupied: to the nearest free one
    # half a cell back: the surface is the occupied cells' boundary, between two samples
    phi = np.where(occ, -(inside - 0.5 * h), outside - 0.5 * h)
    grad = np.stack(np.gradient(phi, h), axis=-1)
    norm = np.linalg.norm(grad, axis=-1, keepdims=True)
    up = np.zeros_like(grad)
    up[..., 2] = 1.0
    normal = np.where(norm > 1e-9, grad / np.maximum(norm, 1e-12), up)
    return StaticCollider(
        phi=phi.astype(np.float32),
        normal=normal.astype(np.float32),
        lo=lo.copy(),
        h=h,
        mode=mode,
        friction=float(friction),
        splats=int(near.sum()),
        cells=int(occ.sum()),
        filled=filled,
        fill_height=fill_height,
        closed=closed,
    )


CLOSE_GAP = 2.0
"""Gaps between static cells up to this many dx wide (horizontally, one cell deep) are
closed before the level set is built."""
FILL_RING = 2.0
"""Width of the ring around the simulated footprint (dx) whose static
support sets the height of the unseen support under it."""
FILL_MIN_RING = 0.1
"""The unseen support is filled only when at least this fraction of the ring's columns
(and :data:`FILL_MIN_COLUMNS` of them) hold static cells near the simulated splats'
lowest point (a real capture's table is sparse: 20 % on the shared table scene)."""
FILL_MIN_COLUMNS = 16
FILL_PERCENTILE = 75.0
"""The filled support's top is this percentile of the ring's column tops (the top of
a noisy surface, not its middle)."""


def _fill_support(occ: np.ndarray, origin: np.ndarray, h: float, pts: np.ndarray, refine: int):
    """Fill, in place, the support a capture cannot see: the static cells under the
    simulated splats where they stood (occluded by them in every view).

    Footprint = the columns (cells of side ``h``) under the simulated points, grown by
    one cell. In a band from 2 dx below their lowest point to 2 cells above it, the
    top of the static cells of each column of the ring of :data:`FILL_RING` cells
    around the footprint is read; when at least :data:`FILL_MIN_RING` of the ring's
    columns have one, the footprint's columns lower than the ring's top (:data:`FILL_PERCENTILE`) (or
    without a static cell in the band) are filled from the band's bottom up to it. Returns (columns filled, that height [m] or
    None)."""
    from scipy import ndimage

    nx, ny, nz = occ.shape
    cell = np.floor((pts - origin) / h).astype(np.int64)
    cell = np.clip(cell, 0, np.asarray(occ.shape) - 1)
    foot = np.zeros((nx, ny), dtype=bool)
    foot[cell[:, 0], cell[:, 1]] = True
    foot = ndimage.binary_dilation(foot, iterations=1)
    ring = ndimage.binary_dilation(foot, iterations=int(FILL_RING * refine)) & ~foot
    k0, _k1, has, top = _support_band(occ, origin, h, pts, refine)
    ring_has = has & ring
    if ring_has.sum() < max(FILL_MIN_COLUMNS, FILL_MIN_RING * ring.sum()):
        return 0, None
    k_top = int(np.round(np.percentile(top[ring_has], FILL_PERCENTILE)))
    # every footprint column lower than that (no static cell in the band, or only lower
    # ones: a hole the simulated splats hid) is filled up to it; none is lowered
    empty = foot & (~has | (top < k_top))
    if not empty.any():
        return 0, None
    ii, jj = np.nonzero(empty)
    for k in range(k0, k_top + 1):
        occ[ii, jj, k] = True
    return int(empty.sum()), float(origin[2] + (k_top + 1) * h)


SUPPORT_GAP = 3.0
"""Gaps in the static support near the simulated splats' lowest point up to this many dx
wide (across gravity) are closed: a captured table is sparse (its splats scattered
over the wood, most of them behind the object's own), and a body must not fall
through the holes between them."""


def _support_band(occ: np.ndarray, origin: np.ndarray, h: float, pts: np.ndarray, refine: int):
    """``(k0, k1, has [nx, ny], top [nx, ny])``: the band of levels (cells) from 2 dx below
    the lowest of ``pts`` to 2 cells above it, which columns hold a static cell in it, and
    the highest such cell of each column."""
    nz = occ.shape[2]
    k_low = int(np.clip(np.floor((pts[:, 2].min() - origin[2]) / h), 0, nz - 1))
    k0 = max(0, k_low - 2 * refine)
    k1 = min(nz, k_low + 2)
    band = occ[:, :, k0:k1]
    top = k0 + (k1 - k0 - 1) - np.argmax(band[:, :, ::-1], axis=2)
    return k0, k1, band.any(axis=2), top


def _close_support(
    occ: np.ndarray, origin: np.ndarray, h: float, pts: np.ndarray, refine: int
) -> int:
    """Close, in place, the gaps of the static support near the simulated ``pts``' lowest
    point: in the band of :func:`_support_band`, the columns without a static cell that
    a closing by a disk of :data:`SUPPORT_GAP` dx (across gravity) covers are filled
    from the band's bottom up to the top of the nearest column that has one. Returns
    how many columns were filled."""
    from scipy import ndimage

    k0, k1, has, top = _support_band(occ, origin, h, pts, refine)
    if not has.any():
        return 0
    r = max(1, int(round(SUPPORT_GAP * refine / 2)))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disk = xx**2 + yy**2 <= r * r
    pad = r + 1
    closed = ndimage.binary_closing(np.pad(has, pad), disk)[pad:-pad, pad:-pad]
    gaps = closed & ~has
    if not gaps.any():
        return 0
    _, (ii, jj) = ndimage.distance_transform_edt(~has, return_indices=True)
    height = top[ii, jj]  # the nearest supported column's top
    for k in range(k0, k1):
        occ[:, :, k] |= gaps & (k <= height)
    return int(gaps.sum())


def support_note(
    collider: StaticCollider | None, points: np.ndarray, dx: float, gravity
) -> str | None:
    """One line when the static scene under the simulated ``points`` [P, 3] m is too
    sparse to hold them (or None): the fraction of their footprint (columns of side
    ``dx`` across ``gravity``) that has static cells below them, against
    :data:`SUPPORT_FRACTION`."""
    g = np.asarray(gravity, dtype=np.float64)
    if not float(np.linalg.norm(g)) > 0:
        return None
    down = g / np.linalg.norm(g)
    if abs(down[2]) < 0.99:
        return None  # (a sideways gravity: no floor to check)
    p = np.asarray(points, dtype=np.float64)
    cols = np.floor(p[:, :2] / dx).astype(np.int64)
    keys = np.unique(cols, axis=0)
    # the lowest (along gravity) point of each column
    height = p[:, 2] * (-np.sign(down[2]))
    order = np.lexsort((height, cols[:, 1], cols[:, 0]))
    sorted_cols = cols[order]
    starts = np.r_[0, 1 + np.nonzero((np.diff(sorted_cols, axis=0) != 0).any(axis=1))[0]]
    lowest = p[order[starts]]
    if collider is None:
        supported = 0
    else:
        # look down each column, from just under its lowest point to 4 object heights below
        size = float(np.ptp(p[:, 2])) + dx
        steps = np.arange(0.0, 4.0 * size, 0.5 * collider.h)
        probe = lowest[:, None, :] + steps[None, :, None] * down[None, None, :]
        phi = collider.sample(probe.reshape(-1, 3)).reshape(len(lowest), len(steps))
        supported = int((phi <= 0).any(axis=1).sum())
    frac = supported / max(len(keys), 1)
    if frac >= SUPPORT_FRACTION:
        return None
    return (
        f"static scene: only {100 * frac:.0f} % of the ground under the simulated region is "
        f"static splats at dx = {dx:.3g} m (the static collider is a level set of the cells "
        f"they occupy at {collider.h if collider is not None else dx:.3g} m); the object may "
        "fall through it: a "
        "finer sim.grid, a lower scene.opacity_threshold or a surface_collider in "
        "boundary_conditions holds it"
    )


TILT_WARN_DEG = 20.0
"""A dominant plane of static splats around the region tilted more than this from the
horizontal is said (with the ``scene.up`` that levels it)."""


def tilt_note(static, points: np.ndarray, source_to_world: np.ndarray, seed: int = 0) -> str | None:
    """One line when the static splats around the simulated ``points`` [P, 3] m lie on a
    dominant plane (a floor, a table: at least 30 % of them within 2 % of the region's
    size of it, found by RANSAC) tilted more than :data:`TILT_WARN_DEG` from the world's
    horizontal, with the ``scene.up`` vector (in the capture's frame, through
    ``source_to_world`` [4, 4]) that would level it. None otherwise."""
    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(0), p.max(0)
    ext = float((hi - lo).max())
    if not ext > 0:
        return None
    s = static.means.double().numpy()
    near = s[((s >= lo - ext) & (s <= hi + ext)).all(axis=1)]
    if len(near) < 50:
        return None
    rng = np.random.default_rng(seed)
    tol = 0.02 * ext
    tri = rng.integers(0, len(near), size=(400, 3))
    a, b, c = near[tri[:, 0]], near[tri[:, 1]], near[tri[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 1e-12 * ext * ext
    if not ok.any():
        return None
    n, a = n[ok] / ln[ok, None], a[ok]
    counts = np.array([(np.abs((near - a0) @ n0) < tol).sum() for a0, n0 in zip(a, n, strict=True)])
    best = int(np.argmax(counts))
    inl = near[np.abs((near - a[best]) @ n[best]) < tol]
    if len(inl) < 0.3 * len(near):
        return None
    centre = inl.mean(0)
    normal = np.linalg.svd(inl - centre, full_matrices=False)[2][2]
    if float((p.mean(0) - centre) @ normal) < 0:
        normal = -normal  # towards the simulated splats: the support's up
    angle = float(np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0))))
    if angle <= TILT_WARN_DEG:
        return None
    m = np.asarray(source_to_world, dtype=np.float64)[:3, :3]
    r = m / np.cbrt(np.linalg.det(m))
    u = r.T @ normal
    # the up that levels it replaces the config's: the rest of the rotation stays
    vec = ", ".join(f"{v:.3f}" for v in u)
    return (
        f"scene.up: {100 * len(inl) / len(near):.0f} % of the static splats around the "
        f"region lie on a plane whose normal is {angle:.0f} deg from the world's up (a floor "
        f"or a table, tilted?); if it holds the object, scene.up: [{vec}] (that normal in "
        "the capture's frame, with rotate: []) levels it"
    )
