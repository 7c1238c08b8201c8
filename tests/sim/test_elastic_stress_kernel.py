"""Direct tests of the fast elastic stress kernel and its hand-written adjoint.

``kernels._stress_elastic`` computes, per elastic particle, F_trial = (I + dt C) F, the
fixed corotated Kirchhoff stress tau = 2 mu (F_t - R) F_t^T + lambda (J - 1) J I with R the
polar rotation of F_t (scaled Newton, SVD fallback for det F_t <= 1e-6), and writes
F_out = F_t and affine = -dt vol 4/dx^2 tau + rho vol C. Here it is compared with a
float64 NumPy reference (R from a float64 SVD), and ``_stress_elastic_adjoint`` with
central finite differences of that reference for a random linear functional of
(affine, F_out) w.r.t. F, C, E, nu and density.
"""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.runtime import init_warp

wp = init_warp()

from motionphysics.sim import kernels as K  # noqa: E402

DX = 1.0
DT = 0.5
VOL = 0.25  # -dt vol 4 / dx^2 = -0.5
E0 = 1.0e5
NU0 = 0.3


def _rot(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )


def _random_F(rng, n):
    """F = Q (I + e), Q a random rotation, e a random symmetric strain of 1-10 %."""
    e = rng.normal(size=(n, 3, 3))
    e = 0.5 * (e + np.swapaxes(e, 1, 2))
    e /= np.linalg.norm(e, axis=(1, 2), keepdims=True)
    e *= rng.uniform(0.01, 0.10, size=(n, 1, 1))
    return _rot(rng, n) @ (np.eye(3) + e)


def _degenerate_F(rng, n):
    """det F ~ 5e-7 (<= the 1e-6 threshold): the kernel falls back to the SVD."""
    s = np.stack([rng.uniform(0.95, 1.05, n), rng.uniform(0.9, 0.95, n), np.full(n, 5e-7)], -1)
    return _rot(rng, n) @ (s[:, :, None] * _rot(rng, n))


def _polar_R(F):
    U, _, Vt = np.linalg.svd(F)
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= d[:, None]
    return U @ Vt


def _reference(F, C, E, nu, rho):
    """float64 (F_out, affine) of the kernel's equations, R from an SVD polar decomposition."""
    Ft = (np.eye(3) + DT * C) @ F
    R = _polar_R(Ft)
    mu = E / (2 * (1 + nu))
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    J = np.linalg.det(Ft)
    tau = 2 * mu[:, None, None] * (Ft - R) @ np.swapaxes(Ft, 1, 2) + (lam * (J - 1) * J)[
        :, None, None
    ] * np.eye(3)
    affine = (-DT * VOL * 4 / DX**2) * tau + (rho * VOL)[:, None, None] * C
    return Ft, affine, tau


def _arrays(F, C, E, nu, rho):
    n = F.shape[0]
    f32 = np.float32
    return dict(
        C=wp.array(C.astype(f32), dtype=wp.mat33),
        F=wp.array(F.astype(f32), dtype=wp.mat33),
        ep=wp.zeros(n, dtype=float),
        active=wp.array(np.ones(n, f32), dtype=float),
        volume=wp.array(np.full(n, VOL, f32), dtype=float),
        density=wp.array(rho.astype(f32), dtype=float),
        material_class=wp.array(np.full(n, K.ELASTIC_CLASS, np.int32), dtype=wp.int32),
        E=wp.array(E.astype(f32), dtype=float),
        nu=wp.array(nu.astype(f32), dtype=float),
    )


_IN = ("C", "F", "ep", "active", "volume", "density", "material_class", "E", "nu")


def _forward(a, n):
    F_out = wp.zeros(n, dtype=wp.mat33)
    ep_out = wp.zeros(n, dtype=float)
    affine = wp.zeros(n, dtype=wp.mat33)
    R = wp.zeros(n, dtype=wp.mat33)
    wp.launch(
        K._stress_elastic,
        dim=n,
        inputs=[*(a[k] for k in _IN), DX, DT, 0, 1],
        outputs=[F_out, ep_out, affine, R],
    )
    return F_out.numpy(), affine.numpy(), R


def _params(rng, n):
    E = E0 * rng.uniform(0.5, 2.0, n)
    nu = rng.uniform(0.2, 0.4, n)
    rho = rng.uniform(500.0, 2000.0, n)
    return E, nu, rho


def test_forward_matches_float64_reference():
    rng = np.random.default_rng(12)
    n = 400
    F = _random_F(rng, n)
    E, nu, rho = _params(rng, n)
    C = np.zeros((n, 3, 3))  # affine = -0.5 tau: the stress itself
    F_out, affine, _ = _forward(_arrays(F, C, E, nu, rho), n)
    _, aff_ref, tau_ref = _reference(F.astype(np.float32).astype(np.float64), C, E, nu, rho)
    mu = E / (2 * (1 + nu))
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    # float32: F - R and J - 1 cancel to ~1e-7 absolute (eps 6e-8 times |F| ~ 1, plus the
    # Newton polar's ~1.5e-7), so |affine error| = 0.5 |tau error| <~ (2 mu + 3 lam) * 5e-8
    # in the worst case (measured 2.7e-8); 3e-7 is ~10x the measured maximum.
    err = np.abs(affine - aff_ref).max(axis=(1, 2))
    assert np.all(err <= 3e-7 * (2 * mu + 3 * lam)), err.max()
    # and the stress is not trivially small: 1-10 % strain gives |tau| >= ~0.01 mu
    assert np.all(np.abs(tau_ref).max(axis=(1, 2)) > 5e-3 * mu)
    np.testing.assert_array_equal(F_out, F.astype(np.float32))


def test_forward_with_affine_term_and_rotation_stored():
    rng = np.random.default_rng(3)
    n = 200
    F = _random_F(rng, n)
    E, nu, rho = _params(rng, n)
    C = 0.05 * rng.normal(size=(n, 3, 3))
    F_out, affine, R = _forward(_arrays(F, C, E, nu, rho), n)
    Ft_ref, aff_ref, _ = _reference(F.astype(np.float32).astype(np.float64), C, E, nu, rho)
    mu = E / (2 * (1 + nu))
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    np.testing.assert_allclose(F_out, Ft_ref, atol=1e-6)
    # F_trial itself is rounded to float32 first, hence a 2x looser bound than above.
    tol = 6e-7 * (2 * mu + 3 * lam) + 1e-6 * rho * VOL
    assert np.all(np.abs(affine - aff_ref).max(axis=(1, 2)) <= tol)
    # the stored rotation is the polar rotation (Newton: ~1.5e-7 from the float64 SVD)
    np.testing.assert_allclose(R.numpy(), _polar_R(Ft_ref), atol=2e-6)


def test_forward_degenerate_F_uses_svd_fallback():
    rng = np.random.default_rng(5)
    n = 100
    F = _degenerate_F(rng, n)
    assert np.all(np.linalg.det(F.astype(np.float32).astype(np.float64)) < 1e-6)
    E, nu, rho = _params(rng, n)
    C = np.zeros((n, 3, 3))
    _, affine, R = _forward(_arrays(F, C, E, nu, rho), n)
    assert np.all(np.isfinite(affine))
    Ff = F.astype(np.float32).astype(np.float64)
    R_ref = _polar_R(Ff)
    # float32 svd3 (4 Jacobi sweeps): R to 5e-5-5e-4 (BENCHMARKS.md, MPM; 1.3e-4 measured
    # here); 1e-3 bound
    np.testing.assert_allclose(R.numpy(), R_ref, atol=1e-3)
    Rk = R.numpy().astype(np.float64)
    np.testing.assert_allclose(
        Rk @ np.swapaxes(Rk, 1, 2), np.broadcast_to(np.eye(3), Rk.shape), atol=1e-5
    )
    assert np.all(np.linalg.det(Rk) > 0.999)
    _, aff_ref, _ = _reference(Ff, C, E, nu, rho)
    mu = E / (2 * (1 + nu))
    # |affine error| = 0.5 |tau error| = 0.5 * 2 mu |dR F^T| <= mu * 3 * 1e-3 * |F| (the R
    # bound, 3 terms per entry, |F_ij| <= 1.05); measured 1.0e-4 mu
    err = np.abs(affine - aff_ref).max(axis=(1, 2))
    assert np.all(err <= mu * 3.2e-3), (err / mu).max()


def _loss(F, C, E, nu, rho, W_aff, W_F):
    Ft, aff, _ = _reference(F, C, E, nu, rho)
    return np.sum(W_aff * aff, axis=(1, 2)) + np.sum(W_F * Ft, axis=(1, 2))  # per particle


@pytest.mark.parametrize("with_C", [False, True])
def test_adjoint_matches_finite_differences(with_C):
    rng = np.random.default_rng(7 + int(with_C))
    n = 64
    # inputs exactly representable in float32, so kernel and reference see the same point
    F = _random_F(rng, n).astype(np.float32).astype(np.float64)
    E, nu, rho = (x.astype(np.float32).astype(np.float64) for x in _params(rng, n))
    C = 0.05 * rng.normal(size=(n, 3, 3)) if with_C else np.zeros((n, 3, 3))
    C = C.astype(np.float32).astype(np.float64)
    W_aff = rng.normal(size=(n, 3, 3)) / E0  # scales the stress term to O(1)
    W_F = rng.normal(size=(n, 3, 3))

    a = _arrays(F, C, E, nu, rho)
    _, _, R = _forward(a, n)
    adj = {k: wp.zeros(n, dtype=wp.mat33) for k in ("C", "F")}
    adj.update({k: wp.zeros(n, dtype=float) for k in ("ep", "density", "E", "nu")})
    adj_F_out = wp.array(W_F.astype(np.float32), dtype=wp.mat33)
    adj_ep_out = wp.zeros(n, dtype=float)
    adj_aff = wp.array(W_aff.astype(np.float32), dtype=wp.mat33)
    wp.launch(
        K._stress_elastic_adjoint,
        dim=n,
        inputs=[*(a[k] for k in _IN), DX, DT, 0, R],
        outputs=[
            adj_F_out,
            adj_ep_out,
            adj_aff,
            adj["C"],
            adj["F"],
            adj["ep"],
            adj["density"],
            adj["E"],
            adj["nu"],
        ],
    )
    # output adjoints are consumed
    assert not adj_aff.numpy().any() and not adj_F_out.numpy().any()

    def fd_mat(which):
        g = np.zeros((n, 3, 3))
        base = {"F": F, "C": C}
        h = 1e-6
        for i in range(3):
            for j in range(3):
                p, m = base[which].copy(), base[which].copy()
                p[:, i, j] += h
                m[:, i, j] -= h
                args_p = (p, C) if which == "F" else (F, p)
                args_m = (m, C) if which == "F" else (F, m)
                g[:, i, j] = (
                    _loss(*args_p, E, nu, rho, W_aff, W_F) - _loss(*args_m, E, nu, rho, W_aff, W_F)
                ) / (2 * h)
        return g

    def fd_scalar(which):
        vals = {"E": E, "nu": nu, "rho": rho}
        h = {"E": 1e-3, "nu": 1e-7, "rho": 1e-4}[which]
        p, m = dict(vals), dict(vals)
        p[which] = vals[which] + h
        m[which] = vals[which] - h
        lp = _loss(F, C, p["E"], p["nu"], p["rho"], W_aff, W_F)
        lm = _loss(F, C, m["E"], m["nu"], m["rho"], W_aff, W_F)
        return (lp - lm) / (2 * h)

    # float32 adjoint vs float64 differences (truncation ~h^2 and round-off ~1e-16/h
    # relative: negligible): the kernel's terms are O(1) here, each with ~1e-7-1e-6
    # relative float32 error (max 3.4e-6 of the gradient's magnitude measured over these
    # seeds); 3e-5 is ~10x that and still catches any missing or mis-scaled term.
    # With C = 0 the density gradient is exactly 0 (both sides).
    def check(got, ref, name):
        scale = np.abs(ref).max()
        err = np.abs(got - ref).max()
        assert err <= 3e-5 * scale, f"{name}: max err {err:.3g} vs scale {scale:.3g}"

    check(adj["F"].numpy(), fd_mat("F"), "F")
    check(adj["C"].numpy(), fd_mat("C"), "C")
    check(adj["E"].numpy(), fd_scalar("E"), "E")
    check(adj["nu"].numpy(), fd_scalar("nu"), "nu")
    check(adj["density"].numpy(), fd_scalar("rho"), "density")
