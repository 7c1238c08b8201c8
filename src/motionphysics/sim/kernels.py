"""Warp kernels of the MLS-MPM substep (private; the solver launches them).

One substep (Hu et al. 2018, MLS-MPM with APIC transfers and quadratic B-splines):

1. ``STRESS_KERNELS[class]`` (elastic: ``_stress_elastic``): per particle of that class, F_trial = (I + dt C) F, the material's return map and
   Kirchhoff stress (``constitutive.constitutive``) and the affine matrix
   ``m C - dt V 4/dx^2 tau``; ``_p2g``: scatter of mass and affine momentum
   ``m v + affine (x_i - x_p)`` to the 27 stencil nodes.
   Particles may be split into chunks that each scatter into a PRIVATE grid (leading
   grid dimension), so chunks can run on separate CPU threads without atomics racing.
2. ``_grid_update``: sum the private grids, v_i = mv_i / m_i + dt g (nodes with mass).
   Private grids are region-sized vec4 arrays (momentum xyz, mass w: one atomic per
   node) covering the particles' stencils; the node velocity grid is full-sized.
3. ``_g2p``: gather velocity and the APIC matrix C = 4/dx^2 sum w v_i (x_i - x_p)^T,
   advect x, clamp x to stay at least 2 cells inside the grid.

Grid node (i, j, k) sits at ``lo + (i, j, k) dx``. Stencil base indices are clamped
to [0, n - 3], so no kernel ever reads or writes outside the grid arrays on any device.
Grid kernels take the region's index offset and run over the active region (the
nodes the particles' stencils touch) only.
"""

from __future__ import annotations

from motionphysics.runtime import init_warp
from motionphysics.sim.constitutive import (
    MODELS,
    _corotated_tau,
    _polar_rotation,
    lame,
)

wp = init_warp()

# The hand-written adjoint kernels are compiled with -ffp-contract=fast on CPU: the
# compiler may fuse a multiply and an add of DIFFERENT statements into one FMA. Warp emits
# every operation as its own statement, so its default contraction (within one
# expression) leaves the stencil sums as separate vmulss / vaddss; with this flag (what
# nvcc does by default on CUDA) the P2G adjoint took 18 % less time (20k particles,
# measured). Each such kernel is its own Warp module (module options are per module); the
# forward kernels keep the default, so taped and untaped forwards stay bitwise equal.
ADJOINT_CPU_FLAGS = f"{wp.config.cpu_compiler_flags or '-march=native'} -ffp-contract=fast"
_ADJOINT = {
    "enable_backward": False,
    "module": "unique",
    "module_options": {"cpu_compiler_flags": ADJOINT_CPU_FLAGS},
}

GRID_MASS_EPS = wp.constant(1.0e-12)
"""Nodes with less mass [kg, sim units] than this are treated as empty."""


@wp.func
def _stencil(x: wp.vec3, lo: wp.vec3, inv_dx: float, dims: wp.vec3i):
    """Base node and fractional offset of the quadratic B-spline stencil of x."""
    gx = (x - lo) * inv_dx
    b0 = wp.clamp(int(wp.floor(gx[0] - 0.5)), 0, dims[0] - 3)
    b1 = wp.clamp(int(wp.floor(gx[1] - 0.5)), 0, dims[1] - 3)
    b2 = wp.clamp(int(wp.floor(gx[2] - 0.5)), 0, dims[2] - 3)
    base = wp.vec3i(b0, b1, b2)
    fx = gx - wp.vec3(float(b0), float(b1), float(b2))
    return base, fx


@wp.func
def _weights(fx: wp.vec3):
    """Quadratic B-spline weights; row r holds the weights of node base + r per axis."""
    a = wp.vec3(1.5, 1.5, 1.5) - fx
    b = fx - wp.vec3(1.0, 1.0, 1.0)
    c = fx - wp.vec3(0.5, 0.5, 0.5)
    w0 = 0.5 * wp.cw_mul(a, a)
    w1 = wp.vec3(0.75, 0.75, 0.75) - wp.cw_mul(b, b)
    w2 = 0.5 * wp.cw_mul(c, c)
    return wp.mat33(w0[0], w0[1], w0[2], w1[0], w1[1], w1[2], w2[0], w2[1], w2[2])


def _make_stress_kernel(cls_id: int):
    model = MODELS[cls_id]

    def _stress(
        C: wp.array(dtype=wp.mat33),
        F: wp.array(dtype=wp.mat33),
        ep: wp.array(dtype=float),
        active: wp.array(dtype=float),
        volume: wp.array(dtype=float),
        density: wp.array(dtype=float),
        material_class: wp.array(dtype=wp.int32),
        E: wp.array(dtype=float),
        nu: wp.array(dtype=float),
        tau_Y: wp.array(dtype=float),
        eta: wp.array(dtype=float),
        theta_fric: wp.array(dtype=float),
        mu: wp.array(dtype=float),
        kappa: wp.array(dtype=float),
        n_hb: wp.array(dtype=float),
        dx: float,
        dt: float,
        p_offset: int,
        F_out: wp.array(dtype=wp.mat33),
        ep_out: wp.array(dtype=float),
        affine_out: wp.array(dtype=wp.mat33),
    ):
        # Per particle of this class: F_trial = (I + dt C) F, return map and Kirchhoff
        # stress, and the APIC affine matrix m C - dt V 4/dx^2 tau that P2G scatters.
        # Particles of other classes are left to their own class's kernel.
        p = wp.tid() + p_offset
        if material_class[p] == cls_id:
            inv_dx = 1.0 / dx
            Cp = C[p]
            F_trial = (wp.identity(n=3, dtype=float) + dt * Cp) * F[p]
            Fe, ep_new, tau = model(
                F_trial,
                Cp,
                ep[p],
                dt,
                E[p],
                nu[p],
                tau_Y[p],
                eta[p],
                theta_fric[p],
                mu[p],
                kappa[p],
                n_hb[p],
            )
            F_out[p] = Fe
            ep_out[p] = ep_new
            vol = volume[p] * active[p]
            affine_out[p] = (-dt * vol * 4.0 * inv_dx * inv_dx) * tau + (density[p] * vol) * Cp

    _stress.__name__ = f"_stress_{cls_id}"
    _stress.__qualname__ = f"_stress_{cls_id}"
    return wp.kernel(_stress)


STRESS_KERNELS = tuple(_make_stress_kernel(c) for c in range(len(MODELS)))
"""One stress kernel per material class (``STRESS_KERNELS[class_id]``), same arguments."""

ELASTIC_CLASS = 0
"""Class id of ``MODELS[0]`` = ``constitutive.fixed_corotated`` (identity return map),
which the solver runs with :data:`_stress_elastic` instead (same equations, faster polar
rotation, and the rotation stored for an SVD-free adjoint under a tape)."""

POLAR_MAX_ITERS = 16
POLAR_DET_MIN = wp.constant(1.0e-6)


@wp.func
def _polar_newton(F: wp.mat33):
    """Rotation R of the polar decomposition F = R S (det F > 0), by scaled Newton iteration.

    X <- (z X + X^-T / z) / 2 with z = det(X)^(-1/3) (Higham 1986) converges quadratically
    to R; measured 3-4x faster than ``constitutive._polar_rotation`` (Warp's float32 svd3,
    4 Jacobi sweeps) and ~100x more accurate (max error 1.5e-7 vs 5e-5-5e-4 against a float64
    SVD for strains of 1-10 %). Inverted or degenerate F (det F <= POLAR_DET_MIN), or no
    convergence in POLAR_MAX_ITERS steps, falls back to ``_polar_rotation`` (a proper
    rotation U V^T from the SVD, as the model defines it)."""
    X = F
    done = int(0)  # noqa: UP018  (a Warp variable mutated in the loop)
    if wp.determinant(F) > POLAR_DET_MIN:
        for _it in range(POLAR_MAX_ITERS):
            r0 = wp.vec3(X[0, 0], X[0, 1], X[0, 2])
            r1 = wp.vec3(X[1, 0], X[1, 1], X[1, 2])
            r2 = wp.vec3(X[2, 0], X[2, 1], X[2, 2])
            c0 = wp.cross(r1, r2)
            c1 = wp.cross(r2, r0)
            c2 = wp.cross(r0, r1)
            d = wp.dot(r0, c0)  # X^-T has rows c0, c1, c2 / d
            if d <= 0.0:
                break
            # z = d^(-1/3); near d = 1 (every step of a small strain) by its Taylor series
            # to e^3, whose first omitted term, 35/243 e^4 < 1.5e-9 for |e| < 0.01, is below
            # float32 round-off: no pow call (~6 % of the fused stress + P2G kernel, measured)
            e = d - 1.0
            z = float(0.0)  # noqa: UP018  (a Warp variable assigned in both branches)
            if wp.abs(e) < 0.01:
                z = 1.0 + e * (-1.0 / 3.0 + e * (2.0 / 9.0 - e * (14.0 / 81.0)))
            else:
                z = wp.pow(d, -1.0 / 3.0)
            a = 0.5 * z
            b = 0.5 / (z * d)
            Xn = wp.mat33(
                a * r0[0] + b * c0[0],
                a * r0[1] + b * c0[1],
                a * r0[2] + b * c0[2],
                a * r1[0] + b * c1[0],
                a * r1[1] + b * c1[1],
                a * r1[2] + b * c1[2],
                a * r2[0] + b * c2[0],
                a * r2[1] + b * c2[1],
                a * r2[2] + b * c2[2],
            )
            diff = Xn - X
            X = Xn
            # quadratic convergence: a step of 3e-5 leaves an error of ~1e-9
            if wp.ddot(diff, diff) < 1.0e-9:
                done = 1
                break
    if done == 0:
        X = _polar_rotation(F)
    return X


@wp.kernel(enable_backward=False)
def _stress_elastic(
    C: wp.array(dtype=wp.mat33),
    F: wp.array(dtype=wp.mat33),
    ep: wp.array(dtype=float),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    material_class: wp.array(dtype=wp.int32),
    E: wp.array(dtype=float),
    nu: wp.array(dtype=float),
    dx: float,
    dt: float,
    p_offset: int,
    store_R: int,
    F_out: wp.array(dtype=wp.mat33),
    ep_out: wp.array(dtype=float),
    affine_out: wp.array(dtype=wp.mat33),
    R_out: wp.array(dtype=wp.mat33),
):
    # STRESS_KERNELS[ELASTIC_CLASS] with the fast polar rotation (fixed_corotated:
    # F_e = F_trial, tau = _corotated_tau(F_trial, R)). With store_R (recorded forward)
    # R goes to R_out, for the SVD-free adjoint _stress_elastic_replay.
    p = wp.tid() + p_offset
    if material_class[p] == ELASTIC_CLASS:
        inv_dx = 1.0 / dx
        Cp = C[p]
        F_trial = (wp.identity(n=3, dtype=float) + dt * Cp) * F[p]
        R = _polar_newton(F_trial)
        mu, lam = lame(E[p], nu[p])
        tau = _corotated_tau(F_trial, R, mu, lam)
        F_out[p] = F_trial
        ep_out[p] = ep[p]
        if store_R != 0:
            R_out[p] = R
        vol = volume[p] * active[p]
        affine_out[p] = (-dt * vol * 4.0 * inv_dx * inv_dx) * tau + (density[p] * vol) * Cp


@wp.func
def _vee(A: wp.mat33):
    return wp.vec3(A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1])


@wp.kernel(**_ADJOINT)
def _stress_elastic_adjoint(
    C: wp.array(dtype=wp.mat33),
    F: wp.array(dtype=wp.mat33),
    ep: wp.array(dtype=float),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    material_class: wp.array(dtype=wp.int32),
    E: wp.array(dtype=float),
    nu: wp.array(dtype=float),
    dx: float,
    dt: float,
    p_offset: int,
    R: wp.array(dtype=wp.mat33),
    adj_F_out: wp.array(dtype=wp.mat33),
    adj_ep_out: wp.array(dtype=float),
    adj_affine: wp.array(dtype=wp.mat33),
    adj_C: wp.array(dtype=wp.mat33),
    adj_F: wp.array(dtype=wp.mat33),
    adj_ep: wp.array(dtype=float),
    adj_density: wp.array(dtype=float),
    adj_E: wp.array(dtype=float),
    adj_nu: wp.array(dtype=float),
):
    # Hand-written adjoint of _stress_elastic given its stored rotations R (no SVD; what
    # Warp generates for _stress_elastic_replay, ~2x faster). Output adjoints are consumed
    # (zeroed). The tau part is constitutive._adj_corotated_tau written out:
    #   a_F += 2 mu (A + A^T) F - 2 mu A^T R + tr(A) lam (2J - 1) J F^-T + R [y]x,
    #   y = (tr(S) I - S)^-1 vee(R^T a_R), a_R = -2 mu A F, S = sym(R^T F);
    #   a_mu = A : 2 (F - R) F^T, a_lam = tr(A) J (J - 1)   (F = F_trial, A = a_tau).
    # Written for few instructions (the kernel is compute-bound): J F^-T as the cofactor
    # matrix (no inverse, no division), vee(R^T B) from its 6 off-diagonal entries, R [y]x
    # row by row as R_i x y, the linear solve by the symmetric cofactors of G, and one
    # reciprocal each of 1 + nu and (1 + nu)(1 - 2 nu) for the Lame parameters and their
    # derivatives (4 divisions per particle instead of 9).
    p = wp.tid() + p_offset
    if material_class[p] == ELASTIC_CLASS:
        inv_dx = 1.0 / dx
        Cp = C[p]
        Fp = F[p]
        M = wp.identity(n=3, dtype=float) + dt * Cp
        Ft = M * Fp
        Rp = R[p]
        Ep = E[p]
        nup = nu[p]
        r1 = 1.0 / (1.0 + nup)
        rD = r1 / (1.0 - 2.0 * nup)  # 1 / D, D = (1 + nu)(1 - 2 nu)
        mu = 0.5 * Ep * r1
        lam = Ep * nup * rD
        vol = volume[p] * active[p]
        rho = density[p]
        a_aff = adj_affine[p]
        A = (-dt * vol * 4.0 * inv_dx * inv_dx) * a_aff
        a_Cp = (rho * vol) * a_aff
        a_rho = vol * wp.ddot(a_aff, Cp)
        # rows of F_trial and its cofactor matrix J F^-T (rows f1 x f2, f2 x f0, f0 x f1)
        f0 = wp.vec3(Ft[0, 0], Ft[0, 1], Ft[0, 2])
        f1 = wp.vec3(Ft[1, 0], Ft[1, 1], Ft[1, 2])
        f2 = wp.vec3(Ft[2, 0], Ft[2, 1], Ft[2, 2])
        k0 = wp.cross(f1, f2)
        k1 = wp.cross(f2, f0)
        k2 = wp.cross(f0, f1)
        J = wp.dot(f0, k0)
        trA = A[0, 0] + A[1, 1] + A[2, 2]
        AFt = A * Ft
        AtFR = wp.transpose(A) * (Ft - Rp)  # (A + A^T) F - A^T R = A F + AtFR
        cJ = trA * lam * (2.0 * J - 1.0)
        aF = 2.0 * mu * (AFt + AtFR) + cJ * wp.mat33(
            k0[0], k0[1], k0[2], k1[0], k1[1], k1[2], k2[0], k2[1], k2[2]
        )
        # S = sym(R^T F), G = tr(S) I - S (symmetric)
        S0 = wp.transpose(Rp) * Ft
        s01 = 0.5 * (S0[0, 1] + S0[1, 0])
        s02 = 0.5 * (S0[0, 2] + S0[2, 0])
        s12 = 0.5 * (S0[1, 2] + S0[2, 1])
        trS = S0[0, 0] + S0[1, 1] + S0[2, 2]
        g00 = trS - S0[0, 0]
        g11 = trS - S0[1, 1]
        g22 = trS - S0[2, 2]
        # b = vee(R^T B), B = a_R = -2 mu A F: (R^T B)_ij = sum_k R_ki B_kj
        B = (-2.0 * mu) * AFt
        c0 = wp.vec3(Rp[0, 0], Rp[1, 0], Rp[2, 0])  # columns of R
        c1 = wp.vec3(Rp[0, 1], Rp[1, 1], Rp[2, 1])
        c2 = wp.vec3(Rp[0, 2], Rp[1, 2], Rp[2, 2])
        d0 = wp.vec3(B[0, 0], B[1, 0], B[2, 0])  # columns of B
        d1 = wp.vec3(B[0, 1], B[1, 1], B[2, 1])
        d2 = wp.vec3(B[0, 2], B[1, 2], B[2, 2])
        b = wp.vec3(
            wp.dot(c2, d1) - wp.dot(c1, d2),
            wp.dot(c0, d2) - wp.dot(c2, d0),
            wp.dot(c1, d0) - wp.dot(c0, d1),
        )
        # y = G^-1 b (G symmetric, off-diagonals -s01, -s02, -s12): cofactors over det
        h00 = g11 * g22 - s12 * s12
        h01 = s01 * g22 + s02 * s12
        h02 = s01 * s12 + s02 * g11
        h11 = g00 * g22 - s02 * s02
        h12 = g00 * s12 + s01 * s02
        h22 = g00 * g11 - s01 * s01
        rG = 1.0 / (g00 * h00 - s01 * h01 - s02 * h02)
        y = rG * wp.vec3(
            h00 * b[0] + h01 * b[1] + h02 * b[2],
            h01 * b[0] + h11 * b[1] + h12 * b[2],
            h02 * b[0] + h12 * b[1] + h22 * b[2],
        )
        # R [y]x: row i is R_i x y
        q0 = wp.cross(wp.vec3(Rp[0, 0], Rp[0, 1], Rp[0, 2]), y)
        q1 = wp.cross(wp.vec3(Rp[1, 0], Rp[1, 1], Rp[1, 2]), y)
        q2 = wp.cross(wp.vec3(Rp[2, 0], Rp[2, 1], Rp[2, 2]), y)
        aF = aF + wp.mat33(q0[0], q0[1], q0[2], q1[0], q1[1], q1[2], q2[0], q2[1], q2[2])
        a_mu = 2.0 * wp.ddot(Ft, AtFR)  # = A : 2 (F - R) F^T (cyclic trace)
        a_lam = trA * J * (J - 1.0)
        # F_out = F_trial = (I + dt C) F
        a_Ft = adj_F_out[p] + aF
        a_Cp = a_Cp + dt * (a_Ft * wp.transpose(Fp))
        adj_F[p] = adj_F[p] + wp.transpose(M) * a_Ft
        adj_C[p] = adj_C[p] + a_Cp
        adj_ep[p] = adj_ep[p] + adj_ep_out[p]
        adj_density[p] = adj_density[p] + a_rho
        # lame: mu = E / (2 (1 + nu)), lam = E nu / D
        adj_E[p] = adj_E[p] + 0.5 * a_mu * r1 + a_lam * nup * rD
        adj_nu[p] = (
            adj_nu[p] - 0.5 * a_mu * Ep * r1 * r1 + a_lam * Ep * (1.0 + 2.0 * nup * nup) * rD * rD
        )
        adj_F_out[p] = wp.mat33()
        adj_ep_out[p] = 0.0
        adj_affine[p] = wp.mat33()


@wp.kernel
def _stress_elastic_replay(
    C: wp.array(dtype=wp.mat33),
    F: wp.array(dtype=wp.mat33),
    ep: wp.array(dtype=float),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    material_class: wp.array(dtype=wp.int32),
    E: wp.array(dtype=float),
    nu: wp.array(dtype=float),
    dx: float,
    dt: float,
    p_offset: int,
    R: wp.array(dtype=wp.mat33),
    F_out: wp.array(dtype=wp.mat33),
    ep_out: wp.array(dtype=float),
    affine_out: wp.array(dtype=wp.mat33),
):
    # Launched only as an adjoint (adjoint=True): _stress_elastic with the stored
    # rotation R as an input. Warp's generated adjoint of this SVD-free body uses the
    # analytic adjoint of constitutive._corotated_tau (dR/dF included), so the stress
    # backward costs no SVD (Warp's adjoint of the full model replays svd3 repeatedly).
    p = wp.tid() + p_offset
    if material_class[p] == ELASTIC_CLASS:
        inv_dx = 1.0 / dx
        Cp = C[p]
        F_trial = (wp.identity(n=3, dtype=float) + dt * Cp) * F[p]
        mu, lam = lame(E[p], nu[p])
        tau = _corotated_tau(F_trial, R[p], mu, lam)
        F_out[p] = F_trial
        ep_out[p] = ep[p]
        vol = volume[p] * active[p]
        affine_out[p] = (-dt * vol * 4.0 * inv_dx * inv_dx) * tau + (density[p] * vol) * Cp


@wp.kernel
def _p2g(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    affine: wp.array(dtype=wp.mat33),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    lo: wp.vec3,
    dx: float,
    dims: wp.vec3i,
    p_offset: int,
    chunk: int,
    off: wp.vec3i,
    object_id: wp.array(dtype=wp.int32),
    obj_stride: int,
    grid_mv: wp.array4d(dtype=wp.vec4),
):
    # Scatter of mass and APIC momentum m v + affine (x_i - x_p) to the 27 stencil nodes,
    # into the private grid of (chunk, object): slot chunk + obj_stride * object_id
    # (obj_stride = 0: one object, object_id not read).
    p = wp.tid() + p_offset
    slot = chunk
    if obj_stride != 0:
        slot = chunk + obj_stride * object_id[p]
    inv_dx = 1.0 / dx
    m = density[p] * volume[p] * active[p]
    A = affine[p]
    mv = m * v[p]
    base, fx = _stencil(x[p], lo, inv_dx, dims)
    r = base - off  # index into the region-sized grid
    w = _weights(fx)
    # m v + A dpos, dpos = (ijk - fx) dx, is built incrementally: it steps by dx A e_axis
    # per node along each axis (as in _p2g_adjoint), ~12 flops per node instead of ~25
    Ae0 = dx * wp.vec3(A[0, 0], A[1, 0], A[2, 0])
    Ae1 = dx * wp.vec3(A[0, 1], A[1, 1], A[2, 1])
    Ae2 = dx * wp.vec3(A[0, 2], A[1, 2], A[2, 2])
    ti = mv - dx * (A * fx)  # at node (0, 0, 0)
    for i in range(3):
        tj = ti
        for j in range(3):
            t = tj
            ab = w[i, 0] * w[j, 1]
            for k in range(3):
                weight = ab * w[k, 2]
                q = weight * t
                # one atomic per node: momentum in xyz, mass in w
                wp.atomic_add(
                    grid_mv,
                    slot,
                    r[0] + i,
                    r[1] + j,
                    r[2] + k,
                    wp.vec4(q[0], q[1], q[2], weight * m),
                )
                t = t + Ae2
            tj = tj + Ae1
        ti = ti + Ae0


@wp.kernel(enable_backward=False)
def _stress_elastic_p2g(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    C: wp.array(dtype=wp.mat33),
    F: wp.array(dtype=wp.mat33),
    ep: wp.array(dtype=float),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    E: wp.array(dtype=float),
    nu: wp.array(dtype=float),
    lo: wp.vec3,
    dx: float,
    dt: float,
    dims: wp.vec3i,
    p_offset: int,
    chunk: int,
    off: wp.vec3i,
    store: int,
    F_out: wp.array(dtype=wp.mat33),
    ep_out: wp.array(dtype=float),
    grid_mv: wp.array4d(dtype=wp.vec4),
    affine_out: wp.array(dtype=wp.mat33),
    R_out: wp.array(dtype=wp.mat33),
):
    # A scene whose particles are all elastic and of one object: _stress_elastic and _p2g
    # in one pass over the particles (the same expressions, so the same results): the
    # affine matrix stays in registers instead of a round trip through memory, the
    # particle's mass terms are read once, one launch instead of two. With store != 0 (a
    # recorded substep) the affine matrix and the polar rotation R also go to affine_out
    # and R_out, what the hand-written adjoints _p2g_adjoint and _stress_elastic_adjoint
    # read (as _stress_elastic with store_R writes them); store = 0 writes neither.
    p = wp.tid() + p_offset
    inv_dx = 1.0 / dx
    Cp = C[p]
    F_trial = (wp.identity(n=3, dtype=float) + dt * Cp) * F[p]
    R = _polar_newton(F_trial)
    mu, lam = lame(E[p], nu[p])
    tau = _corotated_tau(F_trial, R, mu, lam)
    F_out[p] = F_trial
    ep_out[p] = ep[p]
    vol = volume[p] * active[p]
    rho = density[p]
    A = (-dt * vol * 4.0 * inv_dx * inv_dx) * tau + (rho * vol) * Cp
    if store != 0:
        R_out[p] = R
        affine_out[p] = A
    # P2G as in _p2g (m = density * volume * active)
    m = rho * volume[p] * active[p]
    mv = m * v[p]
    base, fx = _stencil(x[p], lo, inv_dx, dims)
    r = base - off
    w = _weights(fx)
    Ae0 = dx * wp.vec3(A[0, 0], A[1, 0], A[2, 0])
    Ae1 = dx * wp.vec3(A[0, 1], A[1, 1], A[2, 1])
    Ae2 = dx * wp.vec3(A[0, 2], A[1, 2], A[2, 2])
    ti = mv - dx * (A * fx)
    for i in range(3):
        tj = ti
        for j in range(3):
            t = tj
            ab = w[i, 0] * w[j, 1]
            for k in range(3):
                weight = ab * w[k, 2]
                q = weight * t
                wp.atomic_add(
                    grid_mv,
                    chunk,
                    r[0] + i,
                    r[1] + j,
                    r[2] + k,
                    wp.vec4(q[0], q[1], q[2], weight * m),
                )
                t = t + Ae2
            tj = tj + Ae1
        ti = ti + Ae0


@wp.func
def _node_velocity(
    grid_mv: wp.array4d(dtype=wp.vec4),
    chunks: int,
    gravity: wp.vec3,
    dt: float,
    i: int,
    j: int,
    k: int,
):
    """A region node's velocity after the grid update: (sum of the chunks' momenta) / mass
    + dt g where it has mass, else zero."""
    q = grid_mv[0, i, j, k]
    if chunks > 1:
        q = q + grid_mv[1, i, j, k]
    m = q[3]
    out = wp.vec3(0.0, 0.0, 0.0)
    if m > GRID_MASS_EPS:
        out = wp.vec3(q[0], q[1], q[2]) / m + dt * gravity
    return out


@wp.kernel
def _grid_update(
    grid_mv: wp.array4d(dtype=wp.vec4),
    chunks: int,
    gravity: wp.vec3,
    dt: float,
    off: wp.vec3i,
    grid_v: wp.array3d(dtype=wp.vec3),
):
    # Launched over the region; grid_mv is region-sized, grid_v full-sized.
    i, j, k = wp.tid()
    grid_v[i + off[0], j + off[1], k + off[2]] = _node_velocity(
        grid_mv, chunks, gravity, dt, i, j, k
    )


@wp.kernel(enable_backward=False)
def _grid_update_rows(
    grid_mv: wp.array4d(dtype=wp.vec4),
    chunks: int,
    gravity: wp.vec3,
    dt: float,
    off: wp.vec3i,
    grid_v: wp.array3d(dtype=wp.vec3),
):
    # _grid_update (the same expressions per node) launched over the region's (i, j) rows,
    # each thread looping over k: a 3-D launch divides the task index into (i, j, k) per
    # node, which cost 2/3 of the kernel (measured 71 -> 25 us over a 21x21x20 region).
    # Untaped substeps only (no generated adjoint).
    i, j = wp.tid()
    for k in range(grid_mv.shape[3]):
        v = _node_velocity(grid_mv, chunks, gravity, dt, i, j, k)
        grid_v[i + off[0], j + off[1], k + off[2]] = v


@wp.kernel(**_ADJOINT)
def _grid_update_adjoint(
    grid_mv: wp.array4d(dtype=wp.vec4),
    chunks: int,
    off: wp.vec3i,
    adj_grid_v: wp.array3d(dtype=wp.vec3),
    adj_grid_mv: wp.array4d(dtype=wp.vec4),
):
    # Hand-written adjoint of _grid_update (what Warp generates, without its replay):
    # v = p / m + dt g at nodes with mass, so a_p = a_v / m, a_m = -(p . a_v) / m^2. Every
    # chunk's private grid gets the same adjoint (q = sum of the chunks' q), ASSIGNED, not
    # accumulated: the region's adjoint grids need no zeroing. The node velocity adjoint is
    # consumed (zeroed), as in Warp's generated adjoint of a store. Launched over the
    # region's (i, j) rows, each thread looping over k (as _grid_update_rows).
    i, j = wp.tid()
    for k in range(grid_mv.shape[3]):
        q = grid_mv[0, i, j, k]
        if chunks > 1:
            q = q + grid_mv[1, i, j, k]
        m = q[3]
        a_v = adj_grid_v[i + off[0], j + off[1], k + off[2]]
        a = wp.vec4(0.0, 0.0, 0.0, 0.0)
        if m > GRID_MASS_EPS:
            rm = 1.0 / m  # one division per node instead of four
            a_p = rm * a_v
            a = wp.vec4(a_p[0], a_p[1], a_p[2], 0.0 - wp.dot(wp.vec3(q[0], q[1], q[2]), a_p) * rm)
        for c in range(chunks):
            adj_grid_mv[c, i, j, k] = a
        adj_grid_v[i + off[0], j + off[1], k + off[2]] = wp.vec3(0.0, 0.0, 0.0)


CONTACT_NORMAL_EPS = wp.constant(1.0e-20)
"""Nodes whose mass-gradient normal is shorter than this [kg/cell] get no contact correction."""


def _make_contact_update(num_objects: int):
    """Grid update of ``num_objects`` velocity fields with multi-field contact.

    Multi-velocity-field MPM contact (Bardenhagen, Brackbill & Sulsky 2000, "The
    material-point method for granular materials", CMAME 187; the normal as in Nairn
    2013 / Homel & Herbold 2017): every object o has its own node mass m_o and momentum
    p_o, v_o = p_o / m_o + dt g. At a node shared with other objects, the centre-of-mass
    velocity is v_cm = sum p / sum m + dt g and the contact normal out of o is
    n_o = (grad M - 2 grad m_o) / |.| (towards the other objects' mass; for two objects
    n_1 = -n_2, so the correction conserves momentum). Where o approaches the others,
    delta = (v_o - v_cm) . n_o > 0, its normal velocity is made that of v_cm; the
    tangential relative velocity w = v_o - v_cm - delta n_o is free (friction 0) or
    reduced by Coulomb friction mu delta (sticking to v_cm when |w| <= mu delta).
    Separation (delta <= 0) is free. Mass gradients are central differences of the node
    masses (one-sided at the region's edge). Every piece is continuous in the momenta,
    so the adjoint (Warp's, recorded on the tape) is exact for the branch taken.

    grid_mv: (num_objects, rx, ry, rz) vec4 region grids (momentum xyz, mass w); grid_v:
    the objects' fields stacked along the first axis, object o at node i + o * nx.
    """
    K = int(num_objects)

    def _contact_update(
        grid_mv: wp.array4d(dtype=wp.vec4),
        gravity: wp.vec3,
        dt: float,
        off: wp.vec3i,
        nx: int,
        friction: float,
        grid_v: wp.array3d(dtype=wp.vec3),
    ):
        i, j, k = wp.tid()
        rx = grid_mv.shape[1]
        ry = grid_mv.shape[2]
        rz = grid_mv.shape[3]
        ip = wp.min(i + 1, rx - 1)
        im = wp.max(i - 1, 0)
        jp = wp.min(j + 1, ry - 1)
        jm = wp.max(j - 1, 0)
        kp = wp.min(k + 1, rz - 1)
        km = wp.max(k - 1, 0)
        M = 0.0
        P = wp.vec3(0.0, 0.0, 0.0)
        gM = wp.vec3(0.0, 0.0, 0.0)
        for o in range(K):
            q = grid_mv[o, i, j, k]
            M = M + q[3]
            P = P + wp.vec3(q[0], q[1], q[2])
            gM = gM + wp.vec3(
                grid_mv[o, ip, j, k][3] - grid_mv[o, im, j, k][3],
                grid_mv[o, i, jp, k][3] - grid_mv[o, i, jm, k][3],
                grid_mv[o, i, j, kp][3] - grid_mv[o, i, j, km][3],
            )
        v_cm = wp.vec3(0.0, 0.0, 0.0)
        if M > GRID_MASS_EPS:
            v_cm = P / M + dt * gravity
        for o in range(K):
            q = grid_mv[o, i, j, k]
            m = q[3]
            out = wp.vec3(0.0, 0.0, 0.0)
            if m > GRID_MASS_EPS:
                out = wp.vec3(q[0], q[1], q[2]) / m + dt * gravity
                if M - m > GRID_MASS_EPS:
                    gm = wp.vec3(
                        grid_mv[o, ip, j, k][3] - grid_mv[o, im, j, k][3],
                        grid_mv[o, i, jp, k][3] - grid_mv[o, i, jm, k][3],
                        grid_mv[o, i, j, kp][3] - grid_mv[o, i, j, km][3],
                    )
                    nraw = gM - 2.0 * gm
                    nn = wp.dot(nraw, nraw)
                    if nn > CONTACT_NORMAL_EPS:
                        n = nraw / wp.sqrt(nn)
                        rel = out - v_cm
                        delta = wp.dot(rel, n)
                        if delta > 0.0:
                            w = rel - delta * n
                            if friction > 0.0:
                                lw = wp.length(w)
                                if lw > friction * delta:
                                    out = v_cm + w * (1.0 - friction * delta / lw)
                                else:
                                    out = v_cm
                            else:
                                out = out - delta * n
            grid_v[i + off[0] + o * nx, j + off[1], k + off[2]] = out

    name = f"_contact_update_{K}"
    _contact_update.__name__ = name
    _contact_update.__qualname__ = name
    return wp.kernel(_contact_update)


_CONTACT_KERNELS: dict[int, object] = {}


def contact_update_kernel(num_objects: int):
    """The (cached) :func:`_make_contact_update` kernel for ``num_objects`` fields."""
    kern = _CONTACT_KERNELS.get(num_objects)
    if kern is None:
        kern = _CONTACT_KERNELS[num_objects] = _make_contact_update(num_objects)
    return kern


@wp.kernel
def _bounds(x: wp.array(dtype=wp.vec3), count: int, out: wp.array(dtype=wp.vec3)):
    # Bounding box of all particle positions (one thread; ~1 ns per particle, no atomics).
    lo = x[0]
    hi = x[0]
    for p in range(1, count):
        lo = wp.min(lo, x[p])
        hi = wp.max(hi, x[p])
    out[0] = lo
    out[1] = hi


@wp.func
def _add_index_times(acc: wp.vec3, idx: int, x: wp.vec3):
    """``acc + idx * x`` for a stencil offset ``idx`` in {0, 1, 2}; with the loops unrolled
    ``idx`` is a constant and no multiply by 0 or 1 is left (the compiler may not drop
    ``0.0 * x`` itself: it is NaN for infinite x)."""
    if idx == 1:
        return acc + x
    if idx == 2:
        return acc + 2.0 * x
    return acc


@wp.kernel
def _g2p(
    x: wp.array(dtype=wp.vec3),
    grid_v: wp.array3d(dtype=wp.vec3),
    lo: wp.vec3,
    dx: float,
    dt: float,
    dims: wp.vec3i,
    x_min: wp.vec3,
    x_max: wp.vec3,
    p_offset: int,
    object_id: wp.array(dtype=wp.int32),
    obj_stride: int,
    x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    C_out: wp.array(dtype=wp.mat33),
):
    # grid_v stacks the objects' velocity fields along the first axis (object o at
    # i + o * obj_stride); one object: obj_stride = 0, object_id not read.
    # With W = a_i b_j c_k (the per-axis weights w[., axis]) and dpos = (ijk - fx) dx:
    #   v = sum W g,   B = sum W g dpos^T = dx ([S_i S_j S_k] - v fx^T),
    # S_axis = sum W g * (that axis' stencil index). The sums are taken axis by axis
    # (inner sums over k first, as in _g2p_adjoint): ~10 flops per node instead of ~20.
    p = wp.tid() + p_offset
    inv_dx = 1.0 / dx
    base, fx = _stencil(x[p], lo, inv_dx, dims)
    b0 = base[0]
    if obj_stride != 0:
        b0 = base[0] + obj_stride * object_id[p]
    w = _weights(fx)
    v_new = wp.vec3(0.0, 0.0, 0.0)
    s_i = wp.vec3(0.0, 0.0, 0.0)
    s_j = wp.vec3(0.0, 0.0, 0.0)
    s_k = wp.vec3(0.0, 0.0, 0.0)
    for i in range(3):
        u = wp.vec3(0.0, 0.0, 0.0)
        u_j = wp.vec3(0.0, 0.0, 0.0)
        u_k = wp.vec3(0.0, 0.0, 0.0)
        for j in range(3):
            t = wp.vec3(0.0, 0.0, 0.0)
            t_k = wp.vec3(0.0, 0.0, 0.0)
            for k in range(3):
                g = w[k, 2] * grid_v[b0 + i, base[1] + j, base[2] + k]
                t = t + g
                t_k = _add_index_times(t_k, k, g)
            bt = w[j, 1] * t
            u = u + bt
            u_j = _add_index_times(u_j, j, bt)
            u_k = u_k + w[j, 1] * t_k
        au = w[i, 0] * u
        v_new = v_new + au
        s_i = _add_index_times(s_i, i, au)
        s_j = s_j + w[i, 0] * u_j
        s_k = s_k + w[i, 0] * u_k
    B = dx * (
        wp.mat33(s_i[0], s_j[0], s_k[0], s_i[1], s_j[1], s_k[1], s_i[2], s_j[2], s_k[2])
        - wp.outer(v_new, fx)
    )
    xn = x[p] + dt * v_new
    xn = wp.vec3(
        wp.clamp(xn[0], x_min[0], x_max[0]),
        wp.clamp(xn[1], x_min[1], x_max[1]),
        wp.clamp(xn[2], x_min[2], x_max[2]),
    )
    x_out[p] = xn
    v_out[p] = v_new
    C_out[p] = (4.0 * inv_dx * inv_dx) * B


@wp.func
def _dweights(fx: wp.vec3):
    """d(weights)/d(fx), same layout as :func:`_weights`."""
    d0 = fx - wp.vec3(1.5, 1.5, 1.5)
    d1 = -2.0 * (fx - wp.vec3(1.0, 1.0, 1.0))
    d2 = fx - wp.vec3(0.5, 0.5, 0.5)
    return wp.mat33(d0[0], d0[1], d0[2], d1[0], d1[1], d1[2], d2[0], d2[1], d2[2])


@wp.kernel(**_ADJOINT)
def _g2p_adjoint(
    x: wp.array(dtype=wp.vec3),
    grid_v: wp.array3d(dtype=wp.vec3),
    lo: wp.vec3,
    dx: float,
    dt: float,
    dims: wp.vec3i,
    x_min: wp.vec3,
    x_max: wp.vec3,
    p_offset: int,
    object_id: wp.array(dtype=wp.int32),
    obj_stride: int,
    v_g2p: wp.array(dtype=wp.vec3),
    adj_x_out: wp.array(dtype=wp.vec3),
    adj_v_out: wp.array(dtype=wp.vec3),
    adj_C_out: wp.array(dtype=wp.mat33),
    adj_off: wp.vec3i,
    adj_x: wp.array(dtype=wp.vec3),
    adj_grid_v: wp.array3d(dtype=wp.vec3),
):
    # Hand-written adjoint of _g2p (Warp's generated one replays and stores all 27 stencil
    # terms and is ~6x the forward). With W = a_i b_j c_k (the per-axis weights w[., axis]),
    # dpos = (ijk - fx) dx: v = sum W g, B = sum W g dpos^T, C = 4/dx^2 B,
    # x_out = clamp(x + dt v); ``v_g2p`` is the v the forward computed (v_out before any
    # hook changed it), so no gather is repeated. Node and position adjoints:
    #   a_g = W t_n,  t_n = a_v + a_B dpos_n;
    #   a_x = a_xo - a_B^T v + sum grad W (g_n . t_n),
    # grad W = (a'_i b_j c_k, a_i b'_j c_k, a_i b_j c'_k) / dx, summed axis by axis (inner
    # sums over k first), and t_n built incrementally (t steps by dx a_B e_axis per node):
    # ~17 flops per node instead of ~45. Output adjoints are consumed (zeroed), as in
    # Warp's generated adjoints. adj_grid_v covers the nodes from grid index adj_off (a
    # region-sized private buffer, or the full grid's adjoint with adj_off = 0).
    p = wp.tid() + p_offset
    inv_dx = 1.0 / dx
    base, fx = _stencil(x[p], lo, inv_dx, dims)
    w = _weights(fx)
    dw = _dweights(fx)
    v_new = v_g2p[p]
    xn = x[p] + dt * v_new
    axo = adj_x_out[p]
    # clamp passes the adjoint only where it is inactive
    ax0 = wp.where(xn[0] >= x_min[0] and xn[0] <= x_max[0], axo[0], 0.0)
    ax1 = wp.where(xn[1] >= x_min[1] and xn[1] <= x_max[1], axo[1], 0.0)
    ax2 = wp.where(xn[2] >= x_min[2] and xn[2] <= x_max[2], axo[2], 0.0)
    a_xn = wp.vec3(ax0, ax1, ax2)
    a_v = adj_v_out[p] + dt * a_xn
    a_B = (4.0 * inv_dx * inv_dx) * adj_C_out[p]
    Be0 = dx * wp.vec3(a_B[0, 0], a_B[1, 0], a_B[2, 0])
    Be1 = dx * wp.vec3(a_B[0, 1], a_B[1, 1], a_B[2, 1])
    Be2 = dx * wp.vec3(a_B[0, 2], a_B[1, 2], a_B[2, 2])
    o_i = int(0)  # noqa: UP018  (a Warp variable mutated below)
    if obj_stride != 0:
        o_i = obj_stride * object_id[p]
    b0 = base[0] + o_i
    r = base - adj_off
    r0 = r[0] + o_i
    ti = a_v - dx * (a_B * fx)  # t at node (0, 0, 0)
    gx = float(0.0)  # noqa: UP018  (Warp variables mutated in the loops)
    gy = float(0.0)  # noqa: UP018
    gz = float(0.0)  # noqa: UP018
    for i in range(3):
        tj = ti
        gxi = float(0.0)  # noqa: UP018
        gyi = float(0.0)  # noqa: UP018
        gzi = float(0.0)  # noqa: UP018
        for j in range(3):
            t = tj
            ab = w[i, 0] * w[j, 1]
            sc = float(0.0)  # noqa: UP018  sum_k c_k (g.t)
            sd = float(0.0)  # noqa: UP018  sum_k c'_k (g.t)
            for k in range(3):
                g = grid_v[b0 + i, base[1] + j, base[2] + k]
                wp.atomic_add(adj_grid_v, r0 + i, r[1] + j, r[2] + k, (ab * w[k, 2]) * t)
                gt = wp.dot(g, t)
                sc = sc + w[k, 2] * gt
                sd = sd + dw[k, 2] * gt
                t = t + Be2
            gxi = gxi + w[j, 1] * sc
            gyi = gyi + dw[j, 1] * sc
            gzi = gzi + w[j, 1] * sd
            tj = tj + Be1
        gx = gx + dw[i, 0] * gxi
        gy = gy + w[i, 0] * gyi
        gz = gz + w[i, 0] * gzi
        ti = ti + Be0
    # sum_n W_n a_B^T g_n = a_B^T v_new
    a_x = a_xn - wp.transpose(a_B) * v_new + inv_dx * wp.vec3(gx, gy, gz)
    adj_x[p] = adj_x[p] + a_x
    adj_x_out[p] = wp.vec3(0.0, 0.0, 0.0)
    adj_v_out[p] = wp.vec3(0.0, 0.0, 0.0)
    adj_C_out[p] = wp.mat33()


@wp.kernel(**_ADJOINT)
def _p2g_adjoint(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    affine: wp.array(dtype=wp.mat33),
    active: wp.array(dtype=float),
    volume: wp.array(dtype=float),
    density: wp.array(dtype=float),
    lo: wp.vec3,
    dx: float,
    dims: wp.vec3i,
    p_offset: int,
    chunk: int,
    off: wp.vec3i,
    object_id: wp.array(dtype=wp.int32),
    obj_stride: int,
    adj_grid_mv: wp.array4d(dtype=wp.vec4),
    adj_x: wp.array(dtype=wp.vec3),
    adj_v: wp.array(dtype=wp.vec3),
    adj_affine: wp.array(dtype=wp.mat33),
    adj_density: wp.array(dtype=float),
):
    # Hand-written adjoint of _p2g. Node n gets q_n = W (m v + A dpos) (xyz) and W m (w),
    # W = a_i b_j c_k, dpos = (ijk - fx) dx, m = density volume active. With node
    # adjoints (a_q, a_m) and s_n = a_q.(m v + A dpos_n) + a_m m:
    #   a_v += m S,  S = sum W a_q;   a_mass += sum W (a_q.v + a_m);
    #   a_A += sum W a_q dpos^T = dx (T - S fx^T),  T = sum W a_q ijk^T;
    #   a_x += sum grad W s_n - A^T S.
    # Sums are taken axis by axis (inner sums over k first) and m v + A dpos is built
    # incrementally (it steps by dx A e_axis per node): ~16 flops per node instead of ~65,
    # measured 28 % faster than the direct 27-term loop.
    p = wp.tid() + p_offset
    slot = chunk
    if obj_stride != 0:
        slot = chunk + obj_stride * object_id[p]
    inv_dx = 1.0 / dx
    vol = volume[p] * active[p]
    m = density[p] * vol
    A = affine[p]
    vp = v[p]
    base, fx = _stencil(x[p], lo, inv_dx, dims)
    r = base - off
    w = _weights(fx)
    dw = _dweights(fx)
    Ae0 = dx * wp.vec3(A[0, 0], A[1, 0], A[2, 0])
    Ae1 = dx * wp.vec3(A[0, 1], A[1, 1], A[2, 1])
    Ae2 = dx * wp.vec3(A[0, 2], A[1, 2], A[2, 2])
    qi = m * vp - dx * (A * fx)  # m v + A dpos at node (0, 0, 0)
    S = wp.vec3(0.0, 0.0, 0.0)
    Ti = wp.vec3(0.0, 0.0, 0.0)
    Tj = wp.vec3(0.0, 0.0, 0.0)
    Tk = wp.vec3(0.0, 0.0, 0.0)
    Sm = float(0.0)  # noqa: UP018  (Warp variables mutated in the loops)
    gx = float(0.0)  # noqa: UP018
    gy = float(0.0)  # noqa: UP018
    gz = float(0.0)  # noqa: UP018
    for i in range(3):
        qj = qi
        Si = wp.vec3(0.0, 0.0, 0.0)
        Tji = wp.vec3(0.0, 0.0, 0.0)
        Tki = wp.vec3(0.0, 0.0, 0.0)
        Smi = float(0.0)  # noqa: UP018
        gxi = float(0.0)  # noqa: UP018
        gyi = float(0.0)  # noqa: UP018
        gzi = float(0.0)  # noqa: UP018
        for j in range(3):
            q = qj
            vk = wp.vec3(0.0, 0.0, 0.0)  # sum_k c_k a_q
            vkk = wp.vec3(0.0, 0.0, 0.0)  # sum_k k c_k a_q
            mk = float(0.0)  # noqa: UP018  sum_k c_k a_m
            sc = float(0.0)  # noqa: UP018  sum_k c_k s
            sd = float(0.0)  # noqa: UP018  sum_k c'_k s
            for k in range(3):
                aq4 = adj_grid_mv[slot, r[0] + i, r[1] + j, r[2] + k]
                aq = wp.vec3(aq4[0], aq4[1], aq4[2])
                sn = wp.dot(aq, q) + aq4[3] * m
                c = w[k, 2]
                sc = sc + c * sn
                sd = sd + dw[k, 2] * sn
                cq = c * aq
                vk = vk + cq
                vkk = _add_index_times(vkk, k, cq)
                mk = mk + c * aq4[3]
                q = q + Ae2
            b = w[j, 1]
            bv = b * vk
            Si = Si + bv
            Tji = _add_index_times(Tji, j, bv)
            Tki = Tki + b * vkk
            Smi = Smi + b * mk
            gxi = gxi + b * sc
            gyi = gyi + dw[j, 1] * sc
            gzi = gzi + b * sd
            qj = qj + Ae1
        a = w[i, 0]
        aS = a * Si
        S = S + aS
        Ti = _add_index_times(Ti, i, aS)
        Tj = Tj + a * Tji
        Tk = Tk + a * Tki
        Sm = Sm + a * Smi
        gx = gx + dw[i, 0] * gxi
        gy = gy + a * gyi
        gz = gz + a * gzi
        qi = qi + Ae0
    a_x = inv_dx * wp.vec3(gx, gy, gz) - wp.transpose(A) * S
    T = wp.mat33(Ti[0], Tj[0], Tk[0], Ti[1], Tj[1], Tk[1], Ti[2], Tj[2], Tk[2])
    adj_x[p] = adj_x[p] + a_x
    adj_v[p] = adj_v[p] + m * S
    adj_affine[p] = adj_affine[p] + dx * (T - wp.outer(S, fx))
    adj_density[p] = adj_density[p] + (wp.dot(S, vp) + Sm) * vol


@wp.kernel
def _copy_state(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    C: wp.array(dtype=wp.mat33),
    F: wp.array(dtype=wp.mat33),
    ep: wp.array(dtype=float),
    x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    C_out: wp.array(dtype=wp.mat33),
    F_out: wp.array(dtype=wp.mat33),
    ep_out: wp.array(dtype=float),
):
    # A differentiable state copy (recorded on a tape, the adjoint flows back).
    p = wp.tid()
    x_out[p] = x[p]
    v_out[p] = v[p]
    C_out[p] = C[p]
    F_out[p] = F[p]
    ep_out[p] = ep[p]


@wp.kernel
def _add_vec3_3d(src: wp.array3d(dtype=wp.vec3), dst: wp.array3d(dtype=wp.vec3)):
    # dst += src (sums the chunks' private adjoint grids; never recorded on a tape)
    i, j, k = wp.tid()
    dst[i, j, k] = dst[i, j, k] + src[i, j, k]


@wp.kernel(enable_backward=False)
def _add_region_vec3(src: wp.array3d(dtype=wp.vec3), off: wp.vec3i, dst: wp.array3d(dtype=wp.vec3)):
    # dst[off + ijk] += src[ijk] (a region-sized private adjoint grid into the full one).
    # Launched over src's (i, j) rows, each thread looping over k (see _grid_update_rows).
    i, j = wp.tid()
    for k in range(src.shape[2]):
        dst[i + off[0], j + off[1], k + off[2]] = (
            dst[i + off[0], j + off[1], k + off[2]] + src[i, j, k]
        )


@wp.kernel(enable_backward=False)
def _copy_region_vec3(
    src: wp.array3d(dtype=wp.vec3),
    src_base: wp.vec3i,
    dst_base: wp.vec3i,
    nz: int,
    dst: wp.array3d(dtype=wp.vec3),
):
    # dst[t + dst_base] <- src[t + src_base] over the box (launched over its (i, j) rows,
    # each thread looping over its nz nodes in k, see _grid_update_rows): a full grid's
    # sub-box into a box-sized array (src_base = box start, dst_base = 0) or back.
    i, j = wp.tid()
    for k in range(nz):
        dst[i + dst_base[0], j + dst_base[1], k + dst_base[2]] = src[
            i + src_base[0], j + src_base[1], k + src_base[2]
        ]


@wp.kernel(enable_backward=False)
def _zero_region_vec3(off: wp.vec3i, nz: int, dst: wp.array3d(dtype=wp.vec3)):
    # dst <- 0 on the sub-box starting at `off` (launched over the box's (i, j) rows, each
    # thread looping over its nz nodes in k, see _grid_update_rows).
    i, j = wp.tid()
    for k in range(nz):
        dst[i + off[0], j + off[1], k + off[2]] = wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def _max_speed_sq(v: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    # Reduction used by the per-frame divergence check (forward only, never taped).
    p = wp.tid()
    s = wp.dot(v[p], v[p])
    if wp.isnan(s) or wp.isinf(s):
        s = 1.0e30
    wp.atomic_max(out, 0, s)
