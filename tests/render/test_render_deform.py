"""SH evaluation, polar rotation, the deformation hook and render_frames (float64, FD checks)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motionphysics.render.camera import orbit_camera
from motionphysics.render.deform import deform_splats, polar_rotation, render_frames
from motionphysics.render.sh import C0, sh_to_rgb
from motionphysics.scene.gaussians import GaussianScene, quat_to_rotmat


def _sphere_quadrature():
    # Gauss-Legendre in cos(theta) x uniform phi: exact for polynomials of degree <= 15.
    x, w = np.polynomial.legendre.leggauss(10)
    phi = np.arange(20) * 2 * np.pi / 20
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    d = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    wt = (w[:, None] * np.full(20, 2 * np.pi / 20)[None]).reshape(-1)
    return torch.tensor(d), torch.tensor(wt)


def test_sh_basis_is_orthonormal_and_matches_3dgs_signs():
    d, w = _sphere_quadrature()
    n = d.shape[0]
    basis = []
    for k in range(16):
        sh = torch.zeros(n, 16, 3, dtype=torch.float64)
        sh[:, k, 0] = 0.05  # small: 0.5 + 0.05 Y stays above the clamp at 0
        basis.append((sh_to_rgb(sh, d)[:, 0] - 0.5) / 0.05)
    Y = torch.stack(basis, 1)  # [n, 16]
    gram = Y.T @ (w[:, None] * Y)
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-10, rtol=0)
    assert Y[0, 0].item() == pytest.approx(C0)
    # Degree 1 in 3DGS order and signs: (-C1 y, C1 z, -C1 x).
    c1 = math.sqrt(3 / (4 * math.pi))
    torch.testing.assert_close(
        Y[:, 1:4], torch.stack([-c1 * d[:, 1], c1 * d[:, 2], -c1 * d[:, 0]], 1)
    )


def test_sh_degree0_clamp_and_gradients(fd_check):
    g = torch.Generator().manual_seed(0)
    sh = torch.randn(4, 1, 3, generator=g, dtype=torch.float64)
    rgb = sh_to_rgb(sh, torch.randn(4, 3, generator=g, dtype=torch.float64))
    torch.testing.assert_close(rgb, (0.5 + C0 * sh[:, 0]).clamp_min(0))
    sh3 = torch.randn(3, 16, 3, generator=g, dtype=torch.float64) * 0.3
    dirs = torch.randn(3, 3, generator=g, dtype=torch.float64)
    wts = torch.rand(3, 3, generator=g, dtype=torch.float64)
    fd_check(lambda s, dd: (sh_to_rgb(s, dd) * wts).sum(), [sh3, dirs])


def test_polar_rotation_properties_and_gradient(fd_check):
    g = torch.Generator().manual_seed(1)
    F = torch.eye(3, dtype=torch.float64) + 0.4 * torch.randn(
        6, 3, 3, generator=g, dtype=torch.float64
    )
    F[0] = torch.eye(3)  # repeated singular values: SVD's own backward is singular here
    F[1] = quat_to_rotmat(torch.tensor([0.3, 0.5, -0.2, 0.7], dtype=torch.float64)) * 1.7
    assert (torch.det(F) > 0).all()
    R = polar_rotation(F)
    eye = torch.eye(3, dtype=torch.float64).expand(6, 3, 3)
    torch.testing.assert_close(R @ R.transpose(1, 2), eye)
    torch.testing.assert_close(torch.det(R), torch.ones(6, dtype=torch.float64))
    S = R.transpose(1, 2) @ F
    torch.testing.assert_close(S, S.transpose(1, 2))
    assert (torch.linalg.eigvalsh(S) > 0).all()
    torch.testing.assert_close(R[0], eye[0])
    # Newton's iteration against the SVD definition R = U diag(1, 1, det(U V^T)) V^T.
    U, _, Vh = torch.linalg.svd(F)
    torch.testing.assert_close(R, U @ Vh, atol=1e-12, rtol=0)
    # An inverted F (det < 0) still gives a proper rotation, via the SVD fallback.
    Fi = F.clone()
    Fi[2] = -Fi[2]
    Ri = polar_rotation(Fi)
    torch.testing.assert_close(torch.det(Ri[2]), torch.tensor(1.0, dtype=torch.float64))
    torch.testing.assert_close(Ri[3:], R[3:])
    W = torch.randn(6, 3, 3, generator=g, dtype=torch.float64)
    fd_check(lambda f: (polar_rotation(f) * W).sum(), [F])


def _tiny_splats(n, degree, seed):
    g = torch.Generator().manual_seed(seed)
    return GaussianScene(
        means=(torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 0.6,
        log_scales=torch.log(0.04 + 0.08 * torch.rand(n, 3, generator=g, dtype=torch.float64)),
        quats=torch.randn(n, 4, generator=g, dtype=torch.float64),
        logit_opacities=torch.randn(n, generator=g, dtype=torch.float64) * 0.5 - 0.3,
        sh=torch.randn(n, (degree + 1) ** 2, 3, generator=g, dtype=torch.float64) * 0.4,
    )


def test_deform_identity_and_rotation():
    splats = _tiny_splats(5, 3, seed=2)
    cam = orbit_camera(30.0, 20.0, 2.0)
    parent = torch.arange(5)
    offset = torch.zeros(5, 3, dtype=torch.float64)
    F = torch.eye(3, dtype=torch.float64).expand(5, 3, 3).clone()
    means, covs, colors = deform_splats(splats, splats.means, F, parent, offset, cam)
    torch.testing.assert_close(means, splats.means)
    torch.testing.assert_close(covs, splats.covariances())
    d = splats.means - cam.position
    torch.testing.assert_close(colors, sh_to_rgb(splats.sh, d))
    # A rigidly rotated splat seen along d looks like the rest splat seen along Q^T d.
    Q = quat_to_rotmat(torch.tensor([0.9, 0.1, -0.3, 0.2], dtype=torch.float64))
    means, covs, colors = deform_splats(
        splats, splats.means, Q.expand(5, 3, 3), parent, offset, cam
    )
    torch.testing.assert_close(colors, sh_to_rgb(splats.sh, d @ Q))
    torch.testing.assert_close(covs, Q @ splats.covariances() @ Q.T)


def test_deform_gradients_through_x_F_and_sh(fd_check):
    splats = _tiny_splats(4, 2, seed=3)
    cam = orbit_camera(30.0, 20.0, 2.0)
    g = torch.Generator().manual_seed(4)
    # Two splats per particle, with offsets (downsampled attachment).
    parent = torch.tensor([0, 0, 1, 1])
    x = torch.randn(2, 3, generator=g, dtype=torch.float64) * 0.2
    offset = torch.randn(4, 3, generator=g, dtype=torch.float64) * 0.05
    F = torch.eye(3, dtype=torch.float64) + 0.3 * torch.randn(
        2, 3, 3, generator=g, dtype=torch.float64
    )
    wm, wc, wr = (
        torch.randn(4, *s, generator=g, dtype=torch.float64) for s in ((3,), (3, 3), (3,))
    )

    def loss(x, F, sh):
        s = GaussianScene(splats.means, splats.log_scales, splats.quats, splats.logit_opacities, sh)
        m, c, col = deform_splats(s, x, F, parent, offset, cam)
        return (m * wm).sum() + (c * wc).sum() * 10 + (col * wr).sum()

    fd_check(loss, [x, F, splats.sh])


@pytest.mark.parametrize("backend", ["warp", pytest.param("torch", marks=pytest.mark.slow)])
def test_render_frames_gradients(backend, fd_check):
    splats = _tiny_splats(3, 1, seed=5)
    sim_scene = SimpleNamespace(
        splats=splats,
        splat_parent=torch.arange(3),
        splat_offset=torch.zeros(3, 3, dtype=torch.float64),
    )
    cam = orbit_camera(30.0, 20.0, 1.6, (0, 0, 0), 50.0, 10, 8)
    g = torch.Generator().manual_seed(6)
    xs = splats.means[None] + 0.05 * torch.randn(2, 3, 3, generator=g, dtype=torch.float64)
    Fs = torch.eye(3, dtype=torch.float64) + 0.2 * torch.randn(
        2, 3, 3, 3, generator=g, dtype=torch.float64
    )
    w = torch.rand(2, 8, 10, 3, generator=g, dtype=torch.float64)

    def loss(xs, Fs):
        return (render_frames(sim_scene, xs, Fs, cam, (1.0, 1.0, 1.0), backend=backend) * w).sum()

    frames = render_frames(sim_scene, xs, Fs, cam)
    assert frames.shape == (2, 8, 10, 3)
    assert (frames < 0.99).any()  # something is drawn
    fd_check(loss, [xs, Fs])
