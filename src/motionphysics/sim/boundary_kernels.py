"""Warp kernels of the boundary conditions and forces (private; ``boundary.py`` launches them).

Every kernel maps SOURCE arrays to DESTINATION arrays element by element and writes
every destination element (identity where it does not act). The launcher in
``boundary.py`` runs them in place (source and destination the same array) when no
tape records, and with saved sources and an exact custom adjoint when one does, so
the argument order is always ``(*inputs, *sources, *destinations, *extra_outputs)``
(extra outputs are written whole from inputs, never in place).

Differentiability: no kernel assigns a component of a local vector (not differentiated
by Warp); new vectors are built instead. Branches (contact, inward motion, static vs
sliding friction, window flags) select between pieces that are continuous in the
velocities, and the adjoint is the derivative of the piece taken.

Grids: ``wp.array3d(dtype=wp.vec3)`` of node velocities [m/s], node (i, j, k) at
``lo + (i, j, k) * dx`` [m]; grid kernels are launched over a sub-box of nodes whose
first index is their ``off`` argument, and read node (i, j, k) of their source at
``(i, j, k) - src_off`` (their last input): ``src_off = 0`` when the source is the full
grid (in place), ``off`` when it is a copy of the sub-box only (a recorded launch). Particles: ``wp.array(dtype=wp.vec3)`` [P].
Learned parameters are one-element arrays (``[0]`` read) so their ``.grad`` collects
the adjoint.
"""

from __future__ import annotations

from motionphysics.runtime import init_warp

wp = init_warp()

MODE_STICKY = wp.constant(0)
MODE_SLIP = wp.constant(1)
MODE_FRICTIONAL = wp.constant(2)

CUT_DAMP_DEPTH = wp.constant(1.5)
"""A cut damps grid velocities only this many cells or more inside its region: the
quadratic stencil of a particle outside the region reaches 1.5 cells into it."""

CONTACT_TOL = wp.constant(1.0e-4)


"""Signed-distance tolerance of contact tests, as a fraction of dx (float32 round-off
of node positions; a node exactly on the plane is in contact)."""


@wp.func
def _node_pos(i: int, j: int, k: int, lo: wp.vec3, dx: float):
    return lo + dx * wp.vec3(float(i), float(j), float(k))


@wp.func
def _in_box(p: wp.vec3, box_lo: wp.vec3, box_hi: wp.vec3, tol: float):
    inside = True
    for a in range(3):
        if p[a] < box_lo[a] - tol or p[a] > box_hi[a] + tol:
            inside = False
    return inside


@wp.func
def _coulomb(vt: wp.vec3, vn_abs: float, friction: float):
    """Tangential velocity after Coulomb friction: |vt| reduced by friction*|vn|, not below 0."""
    lt = wp.length(vt)
    out = wp.vec3(0.0, 0.0, 0.0)
    if lt > friction * vn_abs:
        out = vt * (1.0 - friction * vn_abs / lt)
    return out


# ---------------------------------------------------------------------------- grid


@wp.kernel
def _clamp_grid(
    off: wp.vec3i,
    lo: wp.vec3,
    dx: float,
    box_lo: wp.vec3,
    box_hi: wp.vec3,
    velocity: wp.array(dtype=wp.vec3),
    axis: wp.vec3,
    src_off: wp.vec3i,
    v_src: wp.array3d(dtype=wp.vec3),
    v_dst: wp.array3d(dtype=wp.vec3),
):
    # Dirichlet clamp: components selected by `axis` (0/1 per component) take `velocity`.
    i, j, k = wp.tid()  # launched over a sub-box of the grid starting at `off`
    i = i + off[0]
    j = j + off[1]
    k = k + off[2]
    v = v_src[i - src_off[0], j - src_off[1], k - src_off[2]]
    if _in_box(_node_pos(i, j, k, lo, dx), box_lo, box_hi, CONTACT_TOL * dx):
        v = wp.cw_mul(axis, velocity[0]) + wp.cw_mul(wp.vec3(1.0, 1.0, 1.0) - axis, v)
    v_dst[i, j, k] = v


@wp.kernel
def _bounding_box(
    off: wp.vec3i,
    first: wp.vec3i,
    last: wp.vec3i,
    friction: wp.array(dtype=float),
    src_off: wp.vec3i,
    v_src: wp.array3d(dtype=wp.vec3),
    v_dst: wp.array3d(dtype=wp.vec3),
):
    # Domain walls: at nodes i <= first (low faces) and i >= last (high faces) per axis,
    # the outward component is removed; Coulomb friction then acts on what remains.
    i, j, k = wp.tid()  # launched over a sub-box of the grid starting at `off`
    i = i + off[0]
    j = j + off[1]
    k = k + off[2]
    v = v_src[i - src_off[0], j - src_off[1], k - src_off[2]]
    vx = v[0]
    vy = v[1]
    vz = v[2]
    rx = 0.0
    ry = 0.0
    rz = 0.0
    if i <= first[0] and vx < 0.0:
        rx = vx
        vx = 0.0
    if i >= last[0] and vx > 0.0:
        rx = vx
        vx = 0.0
    if j <= first[1] and vy < 0.0:
        ry = vy
        vy = 0.0
    if j >= last[1] and vy > 0.0:
        ry = vy
        vy = 0.0
    if k <= first[2] and vz < 0.0:
        rz = vz
        vz = 0.0
    if k >= last[2] and vz > 0.0:
        rz = vz
        vz = 0.0
    out = wp.vec3(vx, vy, vz)
    removed = wp.vec3(rx, ry, rz)
    # friction is read only at nodes in contact: its generated adjoint is an atomic add
    # into one address per thread that read it, and over the whole grid that was the
    # largest single cost of the CUDA backward (49 of 99 ms at 20k particles, H200)
    if wp.dot(removed, removed) > 0.0:
        mu = friction[0]
        if mu > 0.0:
            out = _coulomb(out, wp.length(removed), mu)
    v_dst[i, j, k] = out


@wp.kernel
def _surface_collider(
    off: wp.vec3i,
    lo: wp.vec3,
    dx: float,
    point: wp.vec3,
    normal: wp.vec3,
    mode: int,
    friction: wp.array(dtype=float),
    src_off: wp.vec3i,
    v_src: wp.array3d(dtype=wp.vec3),
    v_dst: wp.array3d(dtype=wp.vec3),
):
    # Plane (point, unit normal towards the free side). Nodes on or behind it are in
    # contact: sticky -> 0; slip -> inward normal part removed; frictional -> Coulomb.
    # (Particles behind it are projected onto it after G2P: _project_plane.)
    i, j, k = wp.tid()  # launched over a sub-box of the grid starting at `off`
    i = i + off[0]
    j = j + off[1]
    k = k + off[2]
    v = v_src[i - src_off[0], j - src_off[1], k - src_off[2]]
    d = wp.dot(_node_pos(i, j, k, lo, dx) - point, normal)
    if d <= CONTACT_TOL * dx:
        vn = wp.dot(v, normal)
        if mode == MODE_STICKY:
            v = wp.vec3(0.0, 0.0, 0.0)
        elif vn < 0.0:
            vt = v - vn * normal
            if mode == MODE_SLIP:
                v = vt
            else:
                v = _coulomb(vt, -vn, friction[0])
    v_dst[i, j, k] = v


@wp.kernel
def _cut_grid(
    off: wp.vec3i,
    lo: wp.vec3,
    dx: float,
    use_box: int,
    box_lo: wp.vec3,
    box_hi: wp.vec3,
    point: wp.vec3,
    normal: wp.vec3,
    damping: wp.array(dtype=float),
    src_off: wp.vec3i,
    v_src: wp.array3d(dtype=wp.vec3),
    v_dst: wp.array3d(dtype=wp.vec3),
):
    # Cut region (the box, or the half-space behind the plane), shrunk by CUT_DAMP_DEPTH
    # cells: velocity scaled by 1 - damping. Material in the region is removed (and
    # carries no mass); the nodes within a stencil's reach of the region's surface also
    # carry the remaining material's mass, and damping them held it up.
    i, j, k = wp.tid()  # launched over a sub-box of the grid starting at `off`
    i = i + off[0]
    j = j + off[1]
    k = k + off[2]
    v = v_src[i - src_off[0], j - src_off[1], k - src_off[2]]
    xn = _node_pos(i, j, k, lo, dx)
    inside = False
    depth = CUT_DAMP_DEPTH * dx
    if use_box != 0:
        shrink = wp.vec3(depth, depth, depth)
        inside = _in_box(xn, box_lo + shrink, box_hi - shrink, CONTACT_TOL * dx)
    else:
        inside = wp.dot(xn - point, normal) <= (CONTACT_TOL * dx - depth)
    if inside:
        v = (1.0 - damping[0]) * v
    v_dst[i, j, k] = v


# ----------------------------------------------------------------------- particles


@wp.kernel
def _project_plane(
    point: wp.vec3,
    normal: wp.vec3,
    sticky: int,
    friction: wp.array(dtype=float),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # After G2P: a particle behind a collider plane (signed distance d < 0) is moved onto
    # it (x - d n) and its inward normal velocity removed (sticky: all of it), with
    # Coulomb friction on the tangential velocity (the law the grid applies to the contact
    # nodes; friction[0] = 0 for slip planes). The grid condition acts on nodes, so
    # without this material settles ~half a cell into the plane; without the friction,
    # material resting on the plane slid on a frictionless support (a cone of sand spread
    # to an 8 degree heap). Piecewise smooth: the adjoint is the projection's where it acts.
    p = wp.tid()
    x = x_src[p]
    v = v_src[p]
    d = wp.dot(x - point, normal)
    if d < 0.0:
        x = x - d * normal
        if sticky != 0:
            v = wp.vec3(0.0, 0.0, 0.0)
        else:
            vn = wp.dot(v, normal)
            if vn < 0.0:
                v = _coulomb(v - vn * normal, -vn, friction[0])
    x_dst[p] = x
    v_dst[p] = v


@wp.func
def _clamp_vec(x: wp.vec3, x_min: wp.vec3, x_max: wp.vec3):
    return wp.vec3(
        wp.clamp(x[0], x_min[0], x_max[0]),
        wp.clamp(x[1], x_min[1], x_max[1]),
        wp.clamp(x[2], x_min[2], x_max[2]),
    )


@wp.kernel
def _add_acceleration(
    mask: wp.array(dtype=float),
    accel: wp.array(dtype=wp.vec3),
    dt: float,
    x_min: wp.vec3,
    x_max: wp.vec3,
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # After G2P: dv = dt a, dx = dt^2 a (as if a had been added with gravity on the grid).
    p = wp.tid()
    m = mask[p]
    x = x_src[p]
    v = v_src[p]
    if m > 0.0:
        a = accel[0]
        v = v + (m * dt) * a
        x = _clamp_vec(x + (m * dt * dt) * a, x_min, x_max)
    x_dst[p] = x
    v_dst[p] = v


@wp.kernel
def _add_velocity_change(
    mask: wp.array(dtype=float),
    dv: wp.array(dtype=wp.vec3),
    frac: float,
    dt: float,
    x_min: wp.vec3,
    x_max: wp.vec3,
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # After G2P: the share `frac` of an impulse's velocity change dv [m/s] this substep:
    # v += frac dv, x += dt frac dv (as if it had been on the grid velocities).
    p = wp.tid()
    m = mask[p]
    x = x_src[p]
    v = v_src[p]
    if m > 0.0:
        d = (m * frac) * dv[0]
        v = v + d
        x = _clamp_vec(x + dt * d, x_min, x_max)
    x_dst[p] = x
    v_dst[p] = v


@wp.kernel
def _set_translation_velocity(
    mask: wp.array(dtype=float),
    velocity: wp.array(dtype=wp.vec3),
    axis: wp.vec3,
    v_src: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # Before P2G: selected particles carry the imposed velocity on the masked axes.
    p = wp.tid()
    v = v_src[p]
    if mask[p] > 0.0:
        v = wp.cw_mul(axis, velocity[0]) + wp.cw_mul(wp.vec3(1.0, 1.0, 1.0) - axis, v)
    v_dst[p] = v


@wp.kernel
def _impose_translation(
    mask: wp.array(dtype=float),
    velocity: wp.array(dtype=wp.vec3),
    axis: wp.vec3,
    dt: float,
    x_min: wp.vec3,
    x_max: wp.vec3,
    x_in: wp.array(dtype=wp.vec3),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # After G2P: on the masked axes the particle moves x_in + dt v_imposed exactly.
    p = wp.tid()
    x = x_src[p]
    v = v_src[p]
    if mask[p] > 0.0:
        vi = velocity[0]
        notaxis = wp.vec3(1.0, 1.0, 1.0) - axis
        v = wp.cw_mul(axis, vi) + wp.cw_mul(notaxis, v)
        x = _clamp_vec(wp.cw_mul(axis, x_in[p] + dt * vi) + wp.cw_mul(notaxis, x), x_min, x_max)
    x_dst[p] = x
    v_dst[p] = v


@wp.kernel
def _set_rotation_velocity(
    mask: wp.array(dtype=float),
    center: wp.vec3,
    axis: wp.vec3,
    omega: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # Before P2G: rigid rotation velocity omega * axis x (x - center).
    p = wp.tid()
    v = v_src[p]
    if mask[p] > 0.0:
        v = omega[0] * wp.cross(axis, x[p] - center)
    v_dst[p] = v


@wp.kernel
def _impose_rotation(
    mask: wp.array(dtype=float),
    center: wp.vec3,
    axis: wp.vec3,
    omega: wp.array(dtype=float),
    dt: float,
    x_min: wp.vec3,
    x_max: wp.vec3,
    x_in: wp.array(dtype=wp.vec3),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    C_src: wp.array(dtype=wp.mat33),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
    C_dst: wp.array(dtype=wp.mat33),
):
    # After G2P: exact rotation of x_in by angle omega*dt about the axis (Rodrigues, no
    # radial drift), velocity omega axis x r at the new position, APIC C = the rigid
    # velocity gradient omega [axis]_x.
    p = wp.tid()
    x = x_src[p]
    v = v_src[p]
    C = C_src[p]
    if mask[p] > 0.0:
        w = omega[0]
        theta = w * dt
        r = x_in[p] - center
        c = wp.cos(theta)
        s = wp.sin(theta)
        r_new = c * r + s * wp.cross(axis, r) + ((1.0 - c) * wp.dot(axis, r)) * axis
        x = _clamp_vec(center + r_new, x_min, x_max)
        v = w * wp.cross(axis, r_new)
        C = w * wp.skew(axis)
    x_dst[p] = x
    v_dst[p] = v
    C_dst[p] = C


@wp.kernel
def _zero_frozen_velocity(
    release_at: wp.array(dtype=float),
    now: float,
    v_src: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # Before P2G: particles not yet released (now < release_at) scatter no momentum.
    p = wp.tid()
    v = v_src[p]
    if now < release_at[p]:
        v = wp.vec3(0.0, 0.0, 0.0)
    v_dst[p] = v


@wp.kernel
def _hold_frozen(
    release_at: wp.array(dtype=float),
    now: float,
    x_in: wp.array(dtype=wp.vec3),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    C_src: wp.array(dtype=wp.mat33),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
    C_dst: wp.array(dtype=wp.mat33),
):
    # After G2P: not-yet-released particles stay at x_in with v = 0 and C = 0 (so the
    # next P2G's F_trial = F: no deformation either).
    p = wp.tid()
    x = x_src[p]
    v = v_src[p]
    C = C_src[p]
    if now < release_at[p]:
        x = x_in[p]
        v = wp.vec3(0.0, 0.0, 0.0)
        C = wp.mat33()
    x_dst[p] = x
    v_dst[p] = v
    C_dst[p] = C


@wp.kernel
def _cut_particles(
    mark: int,
    use_box: int,
    box_lo: wp.vec3,
    box_hi: wp.vec3,
    point: wp.vec3,
    normal: wp.vec3,
    x_in: wp.array(dtype=wp.vec3),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    C_src: wp.array(dtype=wp.mat33),
    active_src: wp.array(dtype=float),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
    C_dst: wp.array(dtype=wp.mat33),
    active_dst: wp.array(dtype=float),
):
    # After G2P: particles inside the cut region (when `mark`) are removed for good;
    # removed particles are held at x_in with v = C = 0 (they carry no mass, so G2P
    # could otherwise carry them anywhere).
    p = wp.tid()
    act = active_src[p]
    if mark != 0 and act > 0.0:
        inside = False
        if use_box != 0:
            inside = _in_box(x_in[p], box_lo, box_hi, 0.0)
        else:
            inside = wp.dot(x_in[p] - point, normal) <= 0.0
        if inside:
            act = 0.0
    x = x_src[p]
    v = v_src[p]
    C = C_src[p]
    if act <= 0.0:
        x = x_in[p]
        v = wp.vec3(0.0, 0.0, 0.0)
        C = wp.mat33()
    active_dst[p] = act
    x_dst[p] = x
    v_dst[p] = v
    C_dst[p] = C


# ------------------------------------------------------------ static collider (level set)
# The static scene of a capture (``scene.region``: the splats outside it) as a signed
# distance phi [m] sampled at ``ls_lo + (i, j, k) * h`` with its unit outward normal
# (``scene.region.StaticCollider``); both are read trilinearly, clamped at the edges.


@wp.func
def _ls_coords(p: wp.vec3, ls_lo: wp.vec3, inv_h: float, shape: wp.vec3i):
    g = (p - ls_lo) * inv_h
    return wp.vec3(
        wp.clamp(g[0], 0.0, float(shape[0] - 1) - 1.0e-4),
        wp.clamp(g[1], 0.0, float(shape[1] - 1) - 1.0e-4),
        wp.clamp(g[2], 0.0, float(shape[2] - 1) - 1.0e-4),
    )


@wp.func
def _ls_phi(phi: wp.array3d(dtype=float), p: wp.vec3, ls_lo: wp.vec3, inv_h: float):
    shape = wp.vec3i(phi.shape[0], phi.shape[1], phi.shape[2])
    g = _ls_coords(p, ls_lo, inv_h, shape)
    i = int(wp.floor(g[0]))
    j = int(wp.floor(g[1]))
    k = int(wp.floor(g[2]))
    tx = g[0] - float(i)
    ty = g[1] - float(j)
    tz = g[2] - float(k)
    c00 = phi[i, j, k] * (1.0 - tx) + phi[i + 1, j, k] * tx
    c10 = phi[i, j + 1, k] * (1.0 - tx) + phi[i + 1, j + 1, k] * tx
    c01 = phi[i, j, k + 1] * (1.0 - tx) + phi[i + 1, j, k + 1] * tx
    c11 = phi[i, j + 1, k + 1] * (1.0 - tx) + phi[i + 1, j + 1, k + 1] * tx
    c0 = c00 * (1.0 - ty) + c10 * ty
    c1 = c01 * (1.0 - ty) + c11 * ty
    return c0 * (1.0 - tz) + c1 * tz


@wp.func
def _ls_normal(nrm: wp.array3d(dtype=wp.vec3), p: wp.vec3, ls_lo: wp.vec3, inv_h: float):
    shape = wp.vec3i(nrm.shape[0], nrm.shape[1], nrm.shape[2])
    g = _ls_coords(p, ls_lo, inv_h, shape)
    i = int(wp.floor(g[0]))
    j = int(wp.floor(g[1]))
    k = int(wp.floor(g[2]))
    tx = g[0] - float(i)
    ty = g[1] - float(j)
    tz = g[2] - float(k)
    c00 = nrm[i, j, k] * (1.0 - tx) + nrm[i + 1, j, k] * tx
    c10 = nrm[i, j + 1, k] * (1.0 - tx) + nrm[i + 1, j + 1, k] * tx
    c01 = nrm[i, j, k + 1] * (1.0 - tx) + nrm[i + 1, j, k + 1] * tx
    c11 = nrm[i, j + 1, k + 1] * (1.0 - tx) + nrm[i + 1, j + 1, k + 1] * tx
    c0 = c00 * (1.0 - ty) + c10 * ty
    c1 = c01 * (1.0 - ty) + c11 * ty
    n = c0 * (1.0 - tz) + c1 * tz
    ln = wp.length(n)
    out = wp.vec3(0.0, 0.0, 1.0)
    if ln > 1.0e-6:
        out = n / ln
    return out


@wp.kernel
def _static_grid(
    off: wp.vec3i,
    lo: wp.vec3,
    dx: float,
    ls_lo: wp.vec3,
    inv_h: float,
    phi: wp.array3d(dtype=float),
    nrm: wp.array3d(dtype=wp.vec3),
    mode: int,
    friction: wp.array(dtype=float),
    src_off: wp.vec3i,
    v_src: wp.array3d(dtype=wp.vec3),
    v_dst: wp.array3d(dtype=wp.vec3),
):
    # Nodes on or inside the static scene (phi <= 0) are in contact with a collider at
    # rest: sticky -> 0; slip -> the velocity into it (along its normal) removed;
    # frictional -> Coulomb on what remains (as _surface_collider, with the level set's
    # normal). Particles that reach behind its surface are projected by _project_levelset.
    i, j, k = wp.tid()
    i = i + off[0]
    j = j + off[1]
    k = k + off[2]
    v = v_src[i - src_off[0], j - src_off[1], k - src_off[2]]
    xn = _node_pos(i, j, k, lo, dx)
    d = _ls_phi(phi, xn, ls_lo, inv_h)
    if d <= CONTACT_TOL * dx:
        if mode == MODE_STICKY:
            v = wp.vec3(0.0, 0.0, 0.0)
        else:
            n = _ls_normal(nrm, xn, ls_lo, inv_h)
            vn = wp.dot(v, n)
            if vn < 0.0:
                vt = v - vn * n
                if mode == MODE_SLIP:
                    v = vt
                else:
                    v = _coulomb(vt, -vn, friction[0])
    v_dst[i, j, k] = v


@wp.kernel
def _project_levelset(
    ls_lo: wp.vec3,
    inv_h: float,
    phi: wp.array3d(dtype=float),
    nrm: wp.array3d(dtype=wp.vec3),
    sticky: int,
    friction: wp.array(dtype=float),
    x_src: wp.array(dtype=wp.vec3),
    v_src: wp.array(dtype=wp.vec3),
    x_dst: wp.array(dtype=wp.vec3),
    v_dst: wp.array(dtype=wp.vec3),
):
    # After G2P: a particle behind the static scene's surface (phi < 0) is moved onto it
    # along the normal (x - phi n) and its velocity into it removed (sticky: all of it),
    # with Coulomb friction on the rest (as _project_plane does for a collider plane).
    p = wp.tid()
    x = x_src[p]
    v = v_src[p]
    d = _ls_phi(phi, x, ls_lo, inv_h)
    if d < 0.0:
        n = _ls_normal(nrm, x, ls_lo, inv_h)
        x = x - d * n
        if sticky != 0:
            v = wp.vec3(0.0, 0.0, 0.0)
        else:
            vn = wp.dot(v, n)
            if vn < 0.0:
                v = _coulomb(v - vn * n, -vn, friction[0])
    x_dst[p] = x
    v_dst[p] = v
