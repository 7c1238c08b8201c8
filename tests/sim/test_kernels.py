"""Kernel-level tests of the MLS-MPM substep: float64 NumPy twin, conservation,
return-mapping invariants of every material class, and the adjoint of every kernel
against central finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.runtime import init_warp
from motionphysics.sim import kernels as K
from motionphysics.sim.model import Model
from motionphysics.sim.solver import Solver
from motionphysics.sim.state import State

wp = init_warp()

DX = 1.0 / 16
DIMS = (17, 17, 17)


def _lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def _weights(fx):
    return np.stack([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2])


def twin_step(x, v, C, F, vol, rho, E, nu, dt, gravity, lo=np.zeros(3), dx=DX, dims=DIMS):
    """Float64 NumPy twin of one substep: P2G (fixed corotated), grid update, G2P."""
    inv_dx = 1.0 / dx
    gm = np.zeros(dims)
    gmv = np.zeros((*dims, 3))
    F_out = np.empty_like(F)
    mu, lam = _lame(E, nu)
    for p in range(x.shape[0]):
        Ft = (np.eye(3) + dt * C[p]) @ F[p]
        U, s, Vt = np.linalg.svd(Ft)
        R = U @ Vt
        J = np.linalg.det(Ft)
        tau = 2 * mu * (Ft - R) @ Ft.T + lam * J * (J - 1) * np.eye(3)
        F_out[p] = Ft
        m = rho * vol[p]
        affine = -dt * vol[p] * 4 * inv_dx**2 * tau + m * C[p]
        gx = (x[p] - lo) * inv_dx
        base = np.floor(gx - 0.5).astype(int)
        fx = gx - base
        w = _weights(fx)
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    wt = w[i, 0] * w[j, 1] * w[k, 2]
                    dpos = (np.array([i, j, k]) - fx) * dx
                    node = (base[0] + i, base[1] + j, base[2] + k)
                    gmv[node] += wt * (m * v[p] + affine @ dpos)
                    gm[node] += wt * m
    gv = np.zeros_like(gmv)
    has = gm > 1e-12
    gv[has] = gmv[has] / gm[has][:, None] + dt * np.asarray(gravity)
    x_out = np.empty_like(x)
    v_out = np.empty_like(v)
    C_out = np.empty_like(C)
    for p in range(x.shape[0]):
        gx = (x[p] - lo) * inv_dx
        base = np.floor(gx - 0.5).astype(int)
        fx = gx - base
        w = _weights(fx)
        vn = np.zeros(3)
        B = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    wt = w[i, 0] * w[j, 1] * w[k, 2]
                    dpos = (np.array([i, j, k]) - fx) * dx
                    g = gv[base[0] + i, base[1] + j, base[2] + k]
                    vn += wt * g
                    B += wt * np.outer(g, dpos)
        x_out[p] = x[p] + dt * vn
        v_out[p] = vn
        C_out[p] = 4 * inv_dx**2 * B
    return x_out, v_out, C_out, F_out, gm, gmv


def _random_state(rng, P, lo=0.35, hi=0.65):
    x = rng.uniform(lo, hi, (P, 3))
    v = rng.normal(0, 0.5, (P, 3))
    C = rng.normal(0, 2.0, (P, 3, 3))
    F = np.eye(3) + rng.normal(0, 0.08, (P, 3, 3))
    return x, v, C, F


def _state(x, v, C, F, requires_grad=False):
    s = State.from_numpy(x, v, requires_grad=requires_grad)
    s.C.assign(np.ascontiguousarray(C, dtype=np.float32))
    s.F.assign(np.ascontiguousarray(F, dtype=np.float32))
    return s


def _model(P, cls="elastic", grav=(0.0, 0.0, 0.0), requires_grad=False, vol=None, **mat):
    mat = mat or {"E": 2.0e4, "nu": 0.3}
    vol = np.full(P, 2e-5) if vol is None else vol
    return Model.from_particles(
        vol,
        {"class": cls, "density": 500.0, **mat},
        (0, 0, 0),
        DX,
        DIMS,
        gravity=grav,
        requires_grad=requires_grad,
    )


@pytest.mark.parametrize("threads", [1, 2])
def test_step_matches_float64_twin(threads):
    rng = np.random.default_rng(1)
    P = 40
    x, v, C, F = _random_state(rng, P)
    vol = rng.uniform(1e-5, 3e-5, P)
    m = _model(P, grav=(0.0, 0.0, -9.8), vol=vol, E=2.0e4, nu=0.3)
    from motionphysics.sim.solver import SolverConfig

    solver = Solver(m, SolverConfig(threads=threads, min_particles_per_thread=1))
    assert solver.chunks == threads
    s_in, s_out = _state(x, v, C, F), State.zeros(P, "cpu")
    dt = 2e-4
    solver.step(s_in, s_out, dt)
    xr, vr, Cr, Fr, gm, gmv = twin_step(x, v, C, F, vol, 500.0, 2.0e4, 0.3, dt, (0, 0, -9.8))
    # float32 kernels vs float64 twin: values are O(1) (C ~ O(10)), sums of <= 27*40 terms;
    # 1e-4 relative (plus a small absolute floor) is ~100x float32 round-off.
    np.testing.assert_allclose(s_out.x.numpy(), xr, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(s_out.v.numpy(), vr, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(s_out.C.numpy(), Cr, rtol=1e-4, atol=2e-3)
    np.testing.assert_allclose(s_out.F.numpy(), Fr, rtol=1e-5, atol=1e-5)
    g = solver.grid
    (ox, oy, oz), (rx, ry, rz) = g.offset, g.mv.shape[1:]
    grid_q = g.mv.numpy().sum(axis=0)
    np.testing.assert_allclose(
        grid_q[..., 3], gm[ox : ox + rx, oy : oy + ry, oz : oz + rz], rtol=1e-5, atol=1e-10
    )
    np.testing.assert_allclose(
        gm.sum(), grid_q[..., 3].sum(), rtol=1e-6
    )  # no mass outside the region
    # node momenta are sums of terms of both signs: absolute tolerance 1e-4 of the largest
    np.testing.assert_allclose(
        grid_q[..., :3],
        gmv[ox : ox + rx, oy : oy + ry, oz : oz + rz],
        rtol=1e-4,
        atol=1e-4 * np.abs(gmv).max(),
    )


def test_transfers_conserve_mass_and_momentum():
    rng = np.random.default_rng(2)
    P = 60
    x, v, C, F = _random_state(rng, P)
    vol = rng.uniform(1e-5, 3e-5, P)
    m = _model(P, vol=vol, E=5.0e3, nu=0.3)
    solver = Solver(m)
    a, b = _state(x, v, C, F), State.zeros(P, "cpu")
    mass = 500.0 * vol
    p0 = (mass[:, None] * v).sum(axis=0)
    dt = 1e-4
    for step in range(20):
        solver.step(a, b, dt)
        if step == 0:
            # P2G: grid mass and momentum equal the particles' (sum_i w_ip = 1, sum_i w_ip (x_i - x_p) = 0)
            q = solver.grid.mv.numpy()
            np.testing.assert_allclose(q[..., 3].sum(), mass.sum(), rtol=1e-5)
            gmom = q[..., :3].sum(axis=(0, 1, 2, 3))
            np.testing.assert_allclose(gmom, p0, rtol=1e-4, atol=1e-9)
        a, b = b, a
    p1 = (mass[:, None] * a.v.numpy()).sum(axis=0)
    # Stress forces sum to zero over nodes and G2P returns the grid momentum: conserved to
    # float32 round-off of ~20 steps of sums over 60 particles (|p| ~ 1e-3 kg m/s).
    np.testing.assert_allclose(p1, p0, rtol=1e-3, atol=2e-8)


def _eval_constitutive(cls, F, C, ep, dt, requires_grad=False, **params):
    """Arrays to launch ``STRESS_KERNELS[class]`` so that its affine output is C - tau.

    With dx = 1, volume = 1 / (4 dt) and density = 4 dt the affine matrix
    m C - dt V 4/dx^2 tau is exactly C - tau (m = 1).
    """
    P = F.shape[0]
    m = Model.from_particles(
        np.full(P, 1.0 / (4.0 * dt)),
        {"class": cls, "density": 4.0 * dt, **params},
        (0, 0, 0),
        DX,
        DIMS,
        requires_grad=requires_grad,
    )
    arrs = {
        "F": wp.array(F.astype(np.float32), dtype=wp.mat33, requires_grad=requires_grad),
        "C": wp.array(C.astype(np.float32), dtype=wp.mat33, requires_grad=requires_grad),
        "ep": wp.array(ep.astype(np.float32), dtype=float, requires_grad=requires_grad),
    }
    out = (
        wp.zeros(P, dtype=wp.mat33, requires_grad=requires_grad),
        wp.zeros(P, dtype=float, requires_grad=requires_grad),
        wp.zeros(P, dtype=wp.mat33, requires_grad=requires_grad),
    )
    pr = m.params
    active = wp.ones(P, dtype=float)
    inputs = [
        arrs["C"],
        arrs["F"],
        arrs["ep"],
        active,
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
        1.0,
        float(dt),
        0,
    ]
    kernel = K.STRESS_KERNELS[MATERIAL_CLASSES.index(cls)]
    return m, arrs, out, inputs, kernel


def _run_constitutive(cls, F, C=None, ep=None, dt=1e-3, **params):
    """(F_e, ep, tau) of every particle (float64 copies)."""
    P = F.shape[0]
    C = np.zeros((P, 3, 3)) if C is None else C
    ep = np.zeros(P) if ep is None else ep
    m, arrs, out, inputs, kernel = _eval_constitutive(cls, F, C, ep, dt, **params)
    wp.launch(kernel, dim=P, inputs=inputs, outputs=list(out))
    Fe, ep_out, affine = (o.numpy().astype(np.float64) for o in out)
    return Fe, ep_out, C.astype(np.float32).astype(np.float64) - affine


def _dev_norm_log(Fe):
    s = np.linalg.svd(Fe, compute_uv=False)
    eps = np.log(s)
    return np.linalg.norm(eps - eps.mean(axis=-1, keepdims=True), axis=-1), eps.sum(axis=-1)


def _big_strain(rng, P, amp=0.3):
    return np.eye(3) + rng.normal(0, amp, (P, 3, 3)) * 0.5 + np.diag([amp, -amp, 0.0])


def test_elastic_stress_is_fixed_corotated():
    rng = np.random.default_rng(3)
    F = np.eye(3) + rng.normal(0, 0.2, (8, 3, 3))
    Fe, ep, tau = _run_constitutive("elastic", F, E=1e4, nu=0.25)
    mu, lam = _lame(1e4, 0.25)
    for p in range(8):
        U, _, Vt = np.linalg.svd(F[p])
        R = U @ Vt
        if np.linalg.det(R) < 0:  # the proper polar rotation
            U[:, -1] *= -1
            R = U @ Vt
        J = np.linalg.det(F[p])
        ref = 2 * mu * (F[p] - R) @ F[p].T + lam * J * (J - 1) * np.eye(3)
        np.testing.assert_allclose(tau[p], ref, rtol=1e-4, atol=1e-3 * mu)
    np.testing.assert_allclose(Fe, F, atol=1e-6)


@pytest.mark.parametrize("cls", ["metal", "plasticine"])
def test_von_mises_return_lands_on_yield_surface(cls):
    rng = np.random.default_rng(4)
    P = 16
    F = _big_strain(rng, P)
    E, nu, tau_Y = 1e4, 0.3, 200.0
    ep0 = np.full(P, 0.1)
    Fe, ep, tau = _run_constitutive(cls, F, ep=ep0, E=E, nu=nu, tau_Y=tau_Y)
    mu, _ = _lame(E, nu)
    dev_norm, tr = _dev_norm_log(Fe)
    y = tau_Y * (np.exp(-2.0 * ep0) if cls == "plasticine" else np.ones(P))  # softened by damage
    s_norm = 2 * mu * dev_norm
    yielded = ep > ep0
    assert yielded.sum() >= P // 2
    np.testing.assert_allclose(s_norm[yielded], np.sqrt(2 / 3) * y[yielded], rtol=2e-3)
    # plastic flow is isochoric: tr(eps) (log J) unchanged
    _, tr0 = _dev_norm_log(F)
    np.testing.assert_allclose(tr, tr0, atol=2e-5)
    # the trial strain's deviator minus the plastic increment: ep increments = dgamma
    d0, _ = _dev_norm_log(F)
    np.testing.assert_allclose((ep - ep0)[yielded], (d0 - dev_norm)[yielded], rtol=1e-3, atol=1e-6)


def test_foam_viscoplastic_matches_paper_formula():
    rng = np.random.default_rng(5)
    P = 12
    F = _big_strain(rng, P)
    E, nu, tau_Y, eta, dt = 1e4, 0.3, 100.0, 20.0, 1e-3
    Fe, ep, _ = _run_constitutive("foam", F, dt=dt, E=E, nu=nu, tau_Y=tau_Y, eta=eta)
    mu, _ = _lame(E, nu)
    d0, _ = _dev_norm_log(F)
    y = 2 * mu * d0 - np.sqrt(2 / 3) * tau_Y  # over-stress of the trial state
    s_expected = 2 * mu * d0 - np.maximum(y, 0) / (1 + eta / (2 * mu * dt))
    d1, _ = _dev_norm_log(Fe)
    np.testing.assert_allclose(2 * mu * d1, s_expected, rtol=2e-3)


def test_foam_default_yield_stress():
    rng = np.random.default_rng(5)
    F = _big_strain(rng, 4)
    m = Model.from_particles(
        np.ones(4),
        {"class": "foam", "density": 1.0, "E": 1e4, "nu": 0.3, "eta": 1.0},
        (0, 0, 0),
        DX,
        DIMS,
    )
    np.testing.assert_allclose(m.params["tau_Y"].numpy(), 0.05 * 1e4)
    del F


def test_sand_drucker_prager_cone():
    rng = np.random.default_rng(6)
    P = 24
    F = _big_strain(rng, P, 0.25)
    F[:8] *= 1.2  # expanding: must project to the cone tip (Sigma = I)
    E, nu, phi = 1e4, 0.3, 30.0
    Fe, ep, _ = _run_constitutive("sand", F, E=E, nu=nu, theta_fric=phi)
    mu, lam = _lame(E, nu)
    s = np.sin(np.radians(phi))
    alpha = np.sqrt(2 / 3) * 2 * s / (3 - s)
    d1, tr1 = _dev_norm_log(Fe)
    _, tr0 = _dev_norm_log(F)
    tip = tr0 >= 0
    assert tip.any() and (~tip).any()
    np.testing.assert_allclose(np.linalg.svd(Fe[tip], compute_uv=False), 1.0, atol=1e-5)
    # inside or on the cone: ||dev eps|| + (3 lam + 2 mu)/(2 mu) tr(eps) alpha <= 0
    f = d1 + (3 * lam + 2 * mu) / (2 * mu) * tr1 * alpha
    assert np.all(f[~tip] <= 1e-4)
    assert np.all(ep >= 0)


def test_newtonian_fluid_resets_F_and_stress():
    rng = np.random.default_rng(7)
    P = 8
    F = np.eye(3) + rng.normal(0, 0.1, (P, 3, 3))
    C = rng.normal(0, 1.0, (P, 3, 3))
    mu, kappa = 0.5, 1e4
    dt = 1e-3
    Fe, _, tau = _run_constitutive("newtonian", F, C=C, dt=dt, mu=mu, kappa=kappa)
    J = np.linalg.det((np.eye(3) + dt * C) @ F)  # the kernel updates F with C first
    np.testing.assert_allclose(Fe, np.cbrt(J)[:, None, None] * np.eye(3), rtol=1e-5, atol=1e-6)
    ref = (J * mu)[:, None, None] * (C + C.transpose(0, 2, 1)) + (0.5 * kappa * (J**2 - 1))[
        :, None, None
    ] * np.eye(3)
    np.testing.assert_allclose(tau, ref, rtol=1e-4, atol=1e-2)


@pytest.mark.parametrize("n", [1.0, 0.5, 1.6])
def test_herschel_bulkley_solves_flow_rule(n):
    rng = np.random.default_rng(8)
    P = 12
    F = _big_strain(rng, P)
    mu, kappa, tau_Y, eta, dt = 1e3, 5e3, 20.0, 2.0, 1e-3
    Fe, ep, _ = _run_constitutive(
        "non_newtonian", F, dt=dt, mu=mu, kappa=kappa, tau_Y=tau_Y, eta=eta, n=n
    )
    d0, _ = _dev_norm_log(F)
    x = ep  # dgamma per particle (ep0 = 0)
    yielded = 2 * mu * d0 > np.sqrt(2 / 3) * tau_Y
    assert yielded.all()
    # g(x) = ||s_trial|| - sqrt(2/3) tau_Y - 2 mu x - eta (x/dt)^n = 0 (relative to ||s_trial||)
    g = 2 * mu * d0 - np.sqrt(2 / 3) * tau_Y - 2 * mu * x - eta * (x / dt) ** n
    np.testing.assert_allclose(g / (2 * mu * d0), 0.0, atol=2e-4)
    if n == 1.0:  # the paper's Bingham formula
        s_new = 2 * mu * d0 - (2 * mu * d0 - np.sqrt(2 / 3) * tau_Y) / (1 + eta / (2 * mu * dt))
        d1, _ = _dev_norm_log(Fe)
        np.testing.assert_allclose(2 * mu * d1, s_new, rtol=1e-3)


# ------------------------------------------------------------------ kernel adjoints


def _fd_check(run, arrays, h_rel=1e-2, rtol=3e-2, n_probe=2, seed=0):
    """Compare tape gradients of L = run() w.r.t. entries of ``arrays`` with central FD.

    ``run(tape_or_None) -> scalar float`` (it launches the kernel and reduces with fixed
    random weights in float64). float32 kernels: FD relative step ~1e-2 keeps round-off
    (~1e-7 / 1e-2) below 1e-4 of the derivative; the tolerance 3e-2 covers the O(h^2)
    truncation of the nonlinear stress terms.
    """
    rng = np.random.default_rng(seed)
    for name, arr in arrays.items():
        tape = wp.Tape()
        grads = run(tape)
        g = grads[name].reshape(-1)
        base = arr.numpy().copy()
        flat = base.reshape(-1)
        idx = rng.choice(flat.size, size=min(n_probe, flat.size), replace=False)
        idx = np.unique(np.append(idx, np.argmax(np.abs(g))))
        for i in idx:
            h = h_rel * max(abs(flat[i]), 1e-1)
            vals = []
            for sgn in (1, -1):
                pert = flat.copy()
                pert[i] += sgn * h
                arr.assign(pert.reshape(base.shape).astype(np.float32))
                vals.append(run(None))
            arr.assign(base)
            fd = (vals[0] - vals[1]) / (2 * h)
            scale = max(np.abs(g).max(), 1e-12)
            assert abs(g[i] - fd) <= rtol * scale, (
                f"{name}[{i}]: tape {g[i]:.6g} vs FD {fd:.6g} (scale {scale:.3g})"
            )


@pytest.mark.parametrize("cls", MATERIAL_CLASSES)
def test_constitutive_adjoint(cls):
    rng = np.random.default_rng(11)
    P = 6
    params = {
        "elastic": {"E": 1e3, "nu": 0.3},
        "plasticine": {"E": 1e3, "nu": 0.3, "tau_Y": 30.0},
        "metal": {"E": 1e3, "nu": 0.3, "tau_Y": 30.0},
        "foam": {"E": 1e3, "nu": 0.3, "eta": 0.5, "tau_Y": 30.0},
        "sand": {"E": 1e3, "nu": 0.3, "theta_fric": 30.0},
        "newtonian": {"mu": 2.0, "kappa": 1e3},
        "non_newtonian": {"mu": 300.0, "kappa": 1e3, "tau_Y": 10.0, "eta": 0.5, "n": 0.8},
    }[cls]
    F = np.eye(3) + rng.normal(0, 0.15, (P, 3, 3))
    if cls == "sand":
        F *= 0.9  # compressed: inside the cone's smooth part
    C = rng.normal(0, 1.0, (P, 3, 3))
    ep = np.full(P, 0.05)
    m, arrs, out, inputs, kernel = _eval_constitutive(
        cls, F, C, ep, 1e-3, requires_grad=True, **params
    )
    wF = rng.normal(size=(P, 3, 3))
    wt = rng.normal(size=(P, 3, 3)) / max(params.get("E", params.get("kappa")), 1.0)
    we = rng.normal(size=P)

    def run(tape):
        for o in out:
            o.zero_()
        if tape is None:
            wp.launch(kernel, dim=P, inputs=inputs, outputs=list(out))
            return float(
                (out[0].numpy() * wF).sum()
                + (out[2].numpy() * wt).sum()
                + (out[1].numpy() * we).sum()
            )
        with tape:
            wp.launch(kernel, dim=P, inputs=inputs, outputs=list(out))
        out[0].grad.assign(wF.astype(np.float32))
        out[1].grad.assign(we.astype(np.float32))
        out[2].grad.assign(wt.astype(np.float32))
        tape.backward()
        res = {k: a.grad.numpy().copy() for k, a in arrs.items()}
        res.update({k: m.params[k].grad.numpy().copy() for k in params})
        tape.zero()
        return res

    probe = {"F": arrs["F"], **{k: m.params[k] for k in params}}
    if cls == "newtonian":
        probe["C"] = arrs["C"]
    _fd_check(run, probe)


def test_transfer_kernels_adjoint():
    """P2G, grid update and G2P adjoints (one full substep, elastic) vs central FD."""
    rng = np.random.default_rng(12)
    P = 12
    x, v, C, F = _random_state(rng, P, 0.4, 0.6)
    m = _model(P, grav=(0.0, 0.0, -9.8), requires_grad=True, E=2e3, nu=0.3)
    solver = Solver(m)
    s_in = _state(x, v, C, F, requires_grad=True)
    s_out = State.zeros(P, "cpu", requires_grad=True)
    grid = solver.make_grid(requires_grad=True)
    dt = 1e-3
    wx, wv, wC, wF = (rng.normal(size=s.shape) for s in (x, v, C, F))

    def run(tape):
        if tape is None:
            solver.step(s_in, s_out, dt, grid=grid)
            o = s_out.numpy()
            return float(
                (o["x"] * wx).sum()
                + (o["v"] * wv).sum()
                + (o["C"] * wC).sum() * 1e-2
                + (o["F"] * wF).sum()
            )
        with tape:
            solver.step(s_in, s_out, dt, grid=grid)
        s_out.x.grad.assign(wx.astype(np.float32))
        s_out.v.grad.assign(wv.astype(np.float32))
        s_out.C.grad.assign((wC * 1e-2).astype(np.float32))
        s_out.F.grad.assign(wF.astype(np.float32))
        tape.backward()
        res = {f: getattr(s_in, f).grad.numpy().copy() for f in ("x", "v", "C", "F")}
        res["E"] = m.params["E"].grad.numpy().copy()
        res["density"] = m.params["density"].grad.numpy().copy()
        tape.zero()
        return res

    _fd_check(
        run,
        {
            "x": s_in.x,
            "v": s_in.v,
            "C": s_in.C,
            "F": s_in.F,
            "E": m.params["E"],
            "density": m.params["density"],
        },
        h_rel=1e-3,
        n_probe=3,
    )


def _arr(a, dtype):
    return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype)


@pytest.mark.parametrize("objects", [1, 2])
def test_hand_written_transfer_adjoints_match_warps_generated_ones(objects):
    """``_p2g_adjoint`` / ``_g2p_adjoint`` (separable, incremental sums) against the adjoint
    Warp generates from ``_p2g`` / ``_g2p`` themselves, with random cotangents on every
    output: the same derivative evaluated two ways, so they agree to float32 round-off
    (1e-4 relative to the largest entry: sums of 27 terms of mixed sign)."""
    rng = np.random.default_rng(5)
    P = 40
    x, v, C, _ = _random_state(rng, P, 0.3, 0.7)
    lo, dx, dims = wp.vec3(0.0, 0.0, 0.0), DX, wp.vec3i(*DIMS)
    off = wp.vec3i(2, 3, 1)
    # one chunk (per object); covers every stencil of x in [0.3, 0.7]
    region = (objects, 14, 13, 15)
    xa, va = _arr(x, wp.vec3), _arr(v, wp.vec3)
    A = _arr(rng.normal(0, 1.0, (P, 3, 3)), wp.mat33)
    active = _arr(np.ones(P), float)
    vol = _arr(rng.uniform(1e-5, 3e-5, P), float)
    rho = _arr(rng.uniform(400, 600, P), float)
    # two objects: each particle scatters into its object's region grid and gathers from
    # its object's field (stacked along the first axis)
    oid = wp.array(rng.integers(0, objects, P).astype(np.int32), dtype=wp.int32)
    p2g_in = [xa, va, A, active, vol, rho, lo, dx, dims, 0, 0, off, oid, 1 if objects > 1 else 0]
    a_mv = _arr(rng.normal(size=(*region, 4)), wp.vec4)

    def zeros_like_inputs(arrs):
        return [wp.zeros_like(a) if isinstance(a, wp.array) else None for a in arrs]

    gen = zeros_like_inputs(p2g_in)
    mv = wp.zeros(region, dtype=wp.vec4)
    wp.launch(
        K._p2g,
        dim=P,
        inputs=p2g_in,
        outputs=[mv],
        adj_inputs=gen,
        adj_outputs=[wp.clone(a_mv)],
        adjoint=True,
        record_tape=False,
    )
    hand = [wp.zeros_like(a) for a in (xa, va, A, rho)]
    wp.launch(K._p2g_adjoint, dim=P, inputs=[*p2g_in, a_mv], outputs=hand, record_tape=False)
    for got, want in zip(hand, (gen[0], gen[1], gen[2], gen[5]), strict=True):
        g, e = got.numpy(), want.numpy()
        np.testing.assert_allclose(g, e, rtol=0, atol=1e-4 * np.abs(e).max())

    grid_v = _arr(rng.normal(size=(objects * DIMS[0], *DIMS[1:], 3)), wp.vec3)
    x_min, x_max = wp.vec3(0.0, 0.0, 0.0), wp.vec3(1.0, 1.0, 1.0)
    dt = 1e-3
    g2p_in = [xa, grid_v, lo, dx, dt, dims, x_min, x_max, 0, oid, DIMS[0] if objects > 1 else 0]
    a_out = [
        _arr(rng.normal(size=(P, 3)), wp.vec3),
        _arr(rng.normal(size=(P, 3)), wp.vec3),
        _arr(rng.normal(size=(P, 3, 3)) * 1e-3, wp.mat33),
    ]
    outs = [wp.zeros(P, dtype=wp.vec3), wp.zeros(P, dtype=wp.vec3), wp.zeros(P, dtype=wp.mat33)]
    gen = zeros_like_inputs(g2p_in)
    wp.launch(
        K._g2p,
        dim=P,
        inputs=g2p_in,
        outputs=outs,
        adj_inputs=gen,
        adj_outputs=[wp.clone(a) for a in a_out],
        adjoint=True,
        record_tape=False,
    )
    wp.launch(K._g2p, dim=P, inputs=g2p_in, outputs=outs, record_tape=False)
    hand_x, hand_g = wp.zeros_like(xa), wp.zeros_like(grid_v)
    wp.launch(
        K._g2p_adjoint,
        dim=P,
        inputs=[*g2p_in, outs[1], *a_out, wp.vec3i(0, 0, 0)],
        outputs=[hand_x, hand_g],
        record_tape=False,
    )
    for got, want in ((hand_x, gen[0]), (hand_g, gen[1])):
        g, e = got.numpy(), want.numpy()
        np.testing.assert_allclose(g, e, rtol=0, atol=1e-4 * np.abs(e).max())
    # the hand-written adjoint consumes its output adjoints, as Warp's do
    assert not np.any(a_out[0].numpy()) and not np.any(a_out[2].numpy())


@pytest.mark.parametrize("chunks", [1, 2])
def test_hand_written_grid_update_adjoint_matches_warps_generated_one(chunks):
    """``_grid_update_adjoint`` against the adjoint Warp generates from ``_grid_update``
    (random momenta, some nodes without mass, a random node-velocity cotangent on the
    region): the same formulas, so the same float32 values up to round-off; it assigns
    every chunk's momentum adjoint and consumes the velocity adjoint."""
    rng = np.random.default_rng(7)
    region = (6, 5, 7)
    q = rng.normal(size=(chunks, *region, 4))
    q[..., 3] = np.abs(q[..., 3]) * 1e-3
    q[:, 1, :, 2, 3] = 0.0  # empty nodes
    mv = _arr(q, wp.vec4)
    off = wp.vec3i(3, 2, 4)
    grid_v = wp.zeros(DIMS, dtype=wp.vec3)
    a_v = np.zeros((*DIMS, 3))
    a_v[3:9, 2:7, 4:11] = rng.normal(size=(*region, 3))
    ins = [mv, chunks, wp.vec3(0.0, 0.0, -9.8), 1e-3, off]
    gen = wp.zeros_like(mv)
    wp.launch(
        K._grid_update,
        dim=region,
        inputs=ins,
        outputs=[grid_v],
        adj_inputs=[gen, 0, None, 0.0, None],
        adj_outputs=[_arr(a_v, wp.vec3)],
        adjoint=True,
        record_tape=False,
    )
    hand = _arr(rng.normal(size=(chunks, *region, 4)), wp.vec4)  # overwritten, not added to
    adj_v = _arr(a_v, wp.vec3)
    wp.launch(
        K._grid_update_adjoint,
        dim=region[:2],  # (i, j) rows, each looping over k
        inputs=[mv, chunks, off, adj_v],
        outputs=[hand],
        record_tape=False,
    )
    # the same formulas up to one reciprocal per node (1 / m, instead of four divisions)
    # and FMA contraction: equal to float32 round-off
    np.testing.assert_allclose(hand.numpy(), gen.numpy(), rtol=2e-5, atol=0)
    assert not np.any(adj_v.numpy())


@pytest.mark.parametrize("chunks", [1, 2])
def test_grid_update_rows_equals_grid_update(chunks):
    """``_grid_update_rows`` (untaped substeps: (i, j) rows, a loop over k) writes the same
    float32 node velocities as the 3-D ``_grid_update``, and nothing outside the region."""
    rng = np.random.default_rng(3)
    region = (6, 5, 7)
    q = rng.normal(size=(chunks, *region, 4))
    q[..., 3] = np.abs(q[..., 3]) * 1e-3
    q[:, 1, :, 2, 3] = 0.0  # empty nodes
    mv = _arr(q, wp.vec4)
    ins = [mv, chunks, wp.vec3(0.0, 0.0, -9.8), 1e-3, wp.vec3i(3, 2, 4)]
    out = []
    for kernel, dim in ((K._grid_update, region), (K._grid_update_rows, region[:2])):
        grid_v = _arr(np.full((*DIMS, 3), 7.0), wp.vec3)
        wp.launch(kernel, dim=dim, inputs=ins, outputs=[grid_v], record_tape=False)
        out.append(grid_v.numpy())
    np.testing.assert_array_equal(out[1], out[0])
    assert np.count_nonzero(out[1] != 7.0) > 0
    assert np.all(out[1][:3] == 7.0) and np.all(out[1][9:] == 7.0)
