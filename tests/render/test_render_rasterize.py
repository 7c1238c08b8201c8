"""Rasteriser: forward against brute-force references, gradients against finite differences."""

import math

import numpy as np
import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.render.camera import orbit_camera
from motionphysics.render.rasterize import (
    ALPHA_MAX,
    ALPHA_MIN,
    T_MIN,
    project_gaussians,
    rasterize,
    rasterize_reference,
)


def random_scene(n, seed, dtype=torch.float64, spread=0.5, scale=0.08, opac=(0.2, 0.9)):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 2 * spread
    A = torch.randn(n, 3, 3, generator=g, dtype=torch.float64) * scale
    covs = A @ A.transpose(1, 2) + (0.2 * scale) ** 2 * torch.eye(3, dtype=torch.float64)
    colors = torch.rand(n, 3, generator=g, dtype=torch.float64)
    o = opac[0] + (opac[1] - opac[0]) * torch.rand(n, generator=g, dtype=torch.float64)
    return [t.to(dtype) for t in (means, covs, colors, o)]


def brute_force(means, covs, colors, opac, cam, bg):
    """Independent float64 loop: every pixel, every splat, the documented image formation."""
    m, S, c, o = (t.detach().double().numpy() for t in (means, covs, colors, opac))
    W2C = cam.world_to_cam.numpy()
    R, t = W2C[:3, :3], W2C[:3, 3]
    H, Wd = cam.height, cam.width
    lim_x, lim_y = 1.3 * 0.5 * Wd / cam.fx, 1.3 * 0.5 * H / cam.fy
    splats = []
    for i in range(len(m)):
        p = R @ m[i] + t
        if p[2] <= 0.01:
            continue
        tx = np.clip(p[0] / p[2], -lim_x, lim_x) * p[2]
        ty = np.clip(p[1] / p[2], -lim_y, lim_y) * p[2]
        J = np.array(
            [
                [cam.fx / p[2], 0, -cam.fx * tx / p[2] ** 2],
                [0, cam.fy / p[2], -cam.fy * ty / p[2] ** 2],
            ]
        )
        cov2 = J @ R @ S[i] @ R.T @ J.T + 0.3 * np.eye(2)
        mu = np.array([cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy])
        splats.append((p[2], mu, np.linalg.inv(cov2), o[i], c[i]))
    splats.sort(key=lambda s: s[0])
    rgb = np.zeros((H, Wd, 3))
    alpha_img = np.zeros((H, Wd))
    for y in range(H):
        for x in range(Wd):
            pix = np.array([x + 0.5, y + 0.5])
            T, acc = 1.0, np.zeros(3)
            for _, mu, con, oi, ci in splats:
                d = pix - mu
                a = min(ALPHA_MAX, oi * math.exp(-0.5 * d @ con @ d))
                s = min(max((a - ALPHA_MIN) / ALPHA_MIN, 0.0), 1.0)
                a = a * s * s * (3 - 2 * s)
                if T * (1 - a) < T_MIN:
                    break
                acc += ci * a * T
                T *= 1 - a
            rgb[y, x] = acc + T * np.asarray(bg)
            alpha_img[y, x] = 1 - T
    return rgb, alpha_img


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_forward_matches_brute_force_loop(backend):
    cam = orbit_camera(40.0, 25.0, 3.0, (0, 0, 0), 50.0, 14, 11)
    means, covs, colors, opac = random_scene(7, seed=1, opac=(0.5, 1.0))
    bg = (0.2, 0.4, 0.9)
    out = rasterize(means, covs, colors, opac, cam, bg, backend=backend)
    rgb, alpha = brute_force(means, covs, colors, opac, cam, bg)
    # float64 throughout: only summation order differs.
    np.testing.assert_allclose(out.rgb.numpy(), rgb, atol=1e-12)
    np.testing.assert_allclose(out.alpha.numpy(), alpha, atol=1e-12)
    assert out.alpha.max() > 0.5  # the scene is actually visible


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_float32_backends_match_dense_float64_reference(backend):
    # 600 splats, 70x50 image: many overlaps, early stops, partially off-screen splats.
    cam = orbit_camera(30.0, 20.0, 2.2, (0, 0, 0), 50.0, 70, 50)
    scene = random_scene(600, seed=2, spread=0.7, scale=0.06, opac=(0.1, 1.0))
    ref = rasterize_reference(*scene, cam, (1.0, 1.0, 1.0))
    out = rasterize(*[t.float() for t in scene], cam, (1.0, 1.0, 1.0), backend=backend)
    # float32 rounding over ~100 composited layers stays near 1e-6; the stop rule at
    # T < 1e-4 can flip on rounding, changing a pixel by at most 1e-4 (the bound asked).
    assert (out.rgb.double() - ref.rgb).abs().max() < 1e-4
    assert (out.alpha.double() - ref.alpha).abs().max() < 1e-4
    covered = ref.alpha > 0.05
    assert ((out.depth.double() - ref.depth).abs()[covered]).max() < 1e-4
    assert covered.float().mean() > 0.2


def test_warp_and_torch_backward_agree_float32():
    cam = orbit_camera(30.0, 20.0, 2.2, (0, 0, 0), 50.0, 48, 40)
    scene = random_scene(300, seed=3, spread=0.6, scale=0.06)
    g = torch.Generator().manual_seed(0)
    w_rgb, w_a, w_d = (torch.rand(40, 48, *s, generator=g) for s in ((3,), (), ()))
    grads = []
    for backend in ("warp", "torch"):
        leaves = [t.float().requires_grad_() for t in scene]
        out = rasterize(*leaves, cam, (0.5, 0.5, 0.5), backend=backend)
        ((out.rgb * w_rgb).sum() + (out.alpha * w_a).sum() + (out.depth * w_d).sum()).backward()
        grads.append([t.grad for t in leaves])
    for gw, gt in zip(*grads, strict=True):
        # float32 accumulation in different orders: relative 1e-4 of the largest entry.
        torch.testing.assert_close(gw, gt, rtol=0, atol=1e-4 * gt.abs().max().item())


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_gradients_match_finite_differences(backend, fd_check):
    cam = orbit_camera(20.0, 30.0, 2.0, (0, 0, 0), 50.0, 12, 10)
    # opacities below 0.7: no 0.99 clamp kink, and T stays far above the 1e-4 stop.
    scene = random_scene(5, seed=4, spread=0.3, scale=0.12, opac=(0.2, 0.7))
    g = torch.Generator().manual_seed(1)
    w_rgb, w_a, w_d = (
        torch.rand(10, 12, *s, generator=g, dtype=torch.float64) for s in ((3,), (), ())
    )

    def loss(means, covs, colors, opac):
        out = rasterize(means, covs, colors, opac, cam, (0.3, 0.6, 0.9), backend=backend)
        return (out.rgb * w_rgb).sum() + (out.alpha * w_a).sum() + 0.1 * (out.depth * w_d).sum()

    fd_check(loss, scene)


def test_smooth_cut_removes_gradient_bias_of_hard_cut():
    # Finite differences with a step big enough to cross many pixels' 1/255 boundaries
    # see the hard cut's jumps; autograd of the hard cut cannot: a biased gradient.
    cam = orbit_camera(20.0, 30.0, 2.0, (0, 0, 0), 50.0, 40, 32)
    means, covs, colors, opac = random_scene(12, seed=5, spread=0.35, scale=0.05, opac=(0.3, 0.9))
    errs = {}
    for cut in ("hard", "smooth"):

        def loss(m, cut=cut):
            return rasterize_reference(m, covs, colors, opac, cam, (1, 1, 1), cut=cut).rgb.sum()

        leaf = means.clone().requires_grad_()
        loss(leaf).backward()
        h = 1e-4  # world metres: about 0.002 px at this distance
        fd = torch.zeros_like(means)
        for i in range(means.numel()):
            d = torch.zeros_like(means).reshape(-1)
            d[i] = h
            d = d.reshape(means.shape)
            fd.reshape(-1)[i] = (loss(means + d) - loss(means - d)) / (2 * h)
        errs[cut] = ((leaf.grad - fd).norm() / fd.norm()).item()
    # Measured: smooth 1.2e-5 (O(h^2) truncation), hard 0.46 (a few of the ~500
    # boundary pixels cross their 1/255 jump within +-h).
    assert errs["smooth"] < 1e-4
    assert errs["hard"] > 0.05


def test_projection_matches_monte_carlo_cov():
    # EWA's linearisation vs sampling the 3D Gaussian and projecting exactly (small splat).
    cam = orbit_camera(10.0, 15.0, 3.0, (0, 0, 0), 45.0, 64, 64)
    mean = torch.tensor([[0.2, -0.1, 0.1]], dtype=torch.float64)
    A = torch.tensor(
        [[0.02, 0.005, 0.0], [0.0, 0.01, 0.003], [0.004, 0.0, 0.015]], dtype=torch.float64
    )
    cov = (A @ A.T)[None]
    proj = project_gaussians(mean, cov, torch.ones(1, dtype=torch.float64), cam)
    g = torch.Generator().manual_seed(0)
    pts = (
        mean
        + torch.randn(200000, 3, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(cov[0]).T
    )
    uv, _ = cam.project(pts)
    emp = torch.cov(uv.T)
    c = proj.conics[0]
    cov2 = torch.linalg.inv(torch.tensor([[c[0], c[1]], [c[1], c[2]]])) - 0.3 * torch.eye(
        2, dtype=torch.float64
    )
    # MC standard error ~ sqrt(2/200000) = 0.3%; linearisation error ~ (sigma/z)^2 < 0.1%.
    torch.testing.assert_close(emp, cov2, rtol=0.02, atol=0.02 * cov2.abs().max().item())
    torch.testing.assert_close(uv.mean(0), proj.means2d[0], rtol=0, atol=0.05)


@pytest.mark.parametrize("tile", [4, 16])
def test_warp_binning_matches_torch_binning(tile):
    from motionphysics.render.rasterize import bin_tiles
    from motionphysics.render.warp_backend import bin_tiles_warp

    cam = orbit_camera(30.0, 20.0, 2.2, (0, 0, 0), 50.0, 70, 50)
    means, covs, _, opac = random_scene(400, seed=6, spread=0.9, scale=0.06, opac=(0.1, 1.0))
    proj = project_gaussians(means.float(), covs.float(), opac.float(), cam)
    a = bin_tiles(proj, 70, 50, tile)
    b = bin_tiles_warp(proj, 70, 50, tile)
    assert torch.equal(a.ids.int(), b.ids) and torch.equal(a.offsets.int(), b.offsets)
    assert a.ids.numel() > 400


def test_behind_camera_and_offscreen_are_culled():
    cam = orbit_camera(0.0, 0.0, 2.0, (0, 0, 0), 45.0, 16, 16)
    means = torch.tensor([[4.0, 0.0, 0.0], [0.0, 0.0, 30.0]])  # behind the camera; far off-screen
    covs = torch.eye(3).expand(2, 3, 3) * 0.01
    out = rasterize(means, covs, torch.ones(2, 3), torch.ones(2), cam, (0.0, 0.0, 0.0))
    assert out.alpha.abs().max() == 0 and out.rgb.abs().max() == 0


def test_empty_scene_and_bad_shapes():
    cam = orbit_camera(0.0, 0.0, 2.0, width=16, height=8)
    out = rasterize(
        torch.zeros(0, 3),
        torch.zeros(0, 3, 3),
        torch.zeros(0, 3),
        torch.zeros(0),
        cam,
        (0.1, 0.2, 0.3),
    )
    assert out.rgb.shape == (8, 16, 3)
    assert torch.allclose(out.rgb, torch.tensor([0.1, 0.2, 0.3]).expand(8, 16, 3))
    with pytest.raises(UserInputError, match="covs"):
        rasterize(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2), cam)
    with pytest.raises(UserInputError, match="backend"):
        rasterize(
            torch.zeros(0, 3),
            torch.zeros(0, 3, 3),
            torch.zeros(0, 3),
            torch.zeros(0),
            cam,
            backend="vulkan",
        )
    with pytest.raises(UserInputError, match="gsplat"):
        rasterize(
            torch.zeros(0, 3),
            torch.zeros(0, 3, 3),
            torch.zeros(0, 3),
            torch.zeros(0),
            cam,
            backend="gsplat",
        )
