"""The motion prior's features against hand-made trajectories, and their gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from motionphysics.priors.motion_features import (
    FEATURE_NAMES,
    G0,
    LOG_FLOOR,
    MotionScene,
    clip_features,
    frame_features,
    polar_rotation,
)

IDX = {n: i for i, n in enumerate(FEATURE_NAMES)}


def _cloud(n=300, extent=(0.2, 0.12, 0.1), centre=(0.1, -0.2, 0.3), seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.5, 0.5, (n, 3)) * np.asarray(extent)
    return torch.tensor(p + np.asarray(centre), dtype=torch.float64)


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _kabsch_rms(a0: np.ndarray, b: np.ndarray) -> float:
    """Independent reference: rms distance of b from the best rotation of a0 (SVD)."""
    a = a0 - a0.mean(0)
    c = b - b.mean(0)
    u, _, vt = np.linalg.svd(c.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(((c - a @ r.T) ** 2).sum(1).mean()))


def test_rigid_drop_moves_only_height_and_time():
    rest = _cloud()
    scene = MotionScene(rest=rest, ground=0.0)
    c0 = rest.mean(0)
    T = 6
    xs, Fs = [], []
    for k in range(T):
        R = _rot_z(0.4 * k)
        drop = torch.tensor([0.0, 0.0, -0.04 * k], dtype=torch.float64)
        xs.append((rest - c0) @ R.T + c0 + drop)
        Fs.append(R.expand(rest.shape[0], 3, 3))
    x, F = torch.stack(xs), torch.stack(Fs)
    t = torch.arange(T, dtype=torch.float64) * 0.05
    f = frame_features(x, F, t, scene)
    L = float((rest.max(0).values - rest.min(0).values).max())
    h = float(c0[2]) - 0.04 * torch.arange(T, dtype=torch.float64)
    torch.testing.assert_close(f[:, IDX["height"]], h / float(c0[2]), atol=1e-9, rtol=0)
    torch.testing.assert_close(f[:, IDX["height_size"]], h / L, atol=1e-9, rtol=0)
    for name in ("drift", "vertical", "spread", "size", "volume"):
        assert f[:, IDX[name]].abs().max() < 1e-5, name
    for name in ("shape", "strain"):  # log(LOG_FLOOR + ~0)
        assert (f[:, IDX[name]].exp() - LOG_FLOOR).abs().max() < 1e-4, name
    # falling all the way: no rebound
    assert f[:, IDX["rebound"]].abs().max() < 1e-9
    # the underside falls with the centroid
    bottom = f[:, IDX["bottom"]]
    torch.testing.assert_close(bottom[1:] - bottom[:-1], torch.full((T - 1,), -0.04 / L).double())
    assert torch.allclose(f[:, IDX["time"]], torch.log1p(t * math.sqrt(G0 / L)))
    assert torch.allclose(f[:, IDX["gravity"]], torch.ones(T, dtype=torch.float64))


def test_a_bounce_reads_its_rebound():
    rest = _cloud()
    scene = MotionScene(rest=rest, ground=0.0)
    h0 = float(rest[:, 2].mean())
    lift = torch.tensor([0.0, -0.1, -0.2, -0.1, -0.15], dtype=torch.float64)  # down, up, down
    x = torch.stack([rest + torch.tensor([0.0, 0.0, float(d)], dtype=torch.float64) for d in lift])
    F = torch.eye(3, dtype=torch.float64).expand(5, rest.shape[0], 3, 3)
    f = frame_features(x, F, torch.arange(5, dtype=torch.float64) * 0.1, scene)
    r = f[:, IDX["rebound"]]
    assert r[:3].abs().max() < 1e-9  # falling: nothing regained
    assert float(r[3]) == pytest.approx(0.1 / 0.2, rel=1e-9)  # half the fall regained
    assert float(r[4]) == pytest.approx(0.05 / 0.2, rel=1e-9)
    assert h0 > 0.2


def test_squash_reads_flattening_spread_strain_and_no_volume_change():
    rest = _cloud(extent=(0.1, 0.1, 0.1))
    scene = MotionScene(rest=rest, ground=0.0)
    c0 = rest.mean(0)
    s = 0.6  # height scaled by s, width by 1/sqrt(s): isochoric
    S = torch.diag(torch.tensor([s**-0.5, s**-0.5, s], dtype=torch.float64))
    x = ((rest - c0) @ S.T + c0 - torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64))[None]
    F = S.expand(1, rest.shape[0], 3, 3)
    f = frame_features(x, F, torch.tensor([0.1], dtype=torch.float64), scene)[0]
    assert f[IDX["vertical"]] == pytest.approx(math.log(s), abs=1e-9)
    assert f[IDX["spread"]] == pytest.approx(-0.5 * math.log(s), abs=1e-9)
    assert f[IDX["volume"]] == pytest.approx(0.0, abs=1e-9)
    strain = float(torch.linalg.matrix_norm(S.T @ S - torch.eye(3, dtype=torch.float64)))
    assert math.exp(f[IDX["strain"]]) - LOG_FLOOR == pytest.approx(strain, rel=1e-6)
    L = float((rest.max(0).values - rest.min(0).values).max())
    ref = _kabsch_rms(rest.numpy(), x[0].numpy()) / L
    assert ref > 0.05
    shape = math.exp(f[IDX["shape"]]) - LOG_FLOOR
    assert shape == pytest.approx(ref, abs=2e-4)  # smoothed at 0 by 1e-4
    assert f[IDX["drift"]] == pytest.approx(0.0, abs=1e-9)
    assert f[IDX["height"]] == pytest.approx((float(c0[2]) - 0.2) / float(c0[2]), rel=1e-9)


def test_spread_puddle_reads_spread_and_the_shape_change_of_a_tumbled_copy_is_zero():
    rest = _cloud(extent=(0.1, 0.1, 0.1), seed=2)
    scene = MotionScene(rest=rest, ground=0.05)
    c0 = rest.mean(0)
    k = 2.5
    S = torch.diag(torch.tensor([k, k, 1.0 / k**2], dtype=torch.float64))
    drift = torch.tensor([0.3, -0.4, 0.0], dtype=torch.float64)
    puddle = (rest - c0) @ S.T + c0 + drift
    R = _rot_z(1.1) @ torch.tensor(
        [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64
    )
    tumbled = (rest - c0) @ R.T + c0
    x = torch.stack([puddle, tumbled])
    F = torch.stack([S.expand(rest.shape[0], 3, 3), R.expand(rest.shape[0], 3, 3)])
    f = frame_features(x, F, torch.tensor([0.2, 0.4], dtype=torch.float64), scene)
    assert f[0, IDX["spread"]] == pytest.approx(math.log(k), abs=1e-9)
    assert f[0, IDX["vertical"]] == pytest.approx(-2 * math.log(k), abs=1e-9)
    L = float((rest.max(0).values - rest.min(0).values).max())
    assert f[0, IDX["drift"]] == pytest.approx(0.5 / L, abs=2e-4)  # smoothed at 0 by 1e-4
    assert math.exp(f[0, IDX["shape"]]) - LOG_FLOOR > 0.1
    # a rigid tumble (rotation about a horizontal axis) is not a shape change or strain
    assert abs(math.exp(f[1, IDX["shape"]]) - LOG_FLOOR) < 1e-6
    assert abs(math.exp(f[1, IDX["strain"]]) - LOG_FLOOR) < 1e-5  # smoothed at 0 by 1e-6


def test_features_ignore_size_and_placement():
    rest = _cloud()
    c0 = rest.mean(0)
    S = torch.diag(torch.tensor([1.3, 1.3, 0.7], dtype=torch.float64))
    x = ((rest - c0) @ S.T + c0 - torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64))[None]
    F = S.expand(1, rest.shape[0], 3, 3)
    t = torch.tensor([0.3], dtype=torch.float64)
    f = frame_features(x, F, t, MotionScene(rest=rest, ground=0.0))
    k, shift = 0.05, torch.tensor([3.0, -2.0, 1.0], dtype=torch.float64)
    # the same motion at 1/20 the size, elsewhere, over a ground 1 m up, in Froude time
    g = frame_features(
        x * k + shift,
        F,
        t * math.sqrt(k),
        MotionScene(rest=rest * k + shift, ground=0.5),
    )
    h = frame_features(
        x * k + shift,
        F,
        t * math.sqrt(k),
        MotionScene(rest=rest * k + shift, ground=float(shift[2])),
    )
    torch.testing.assert_close(h, f, atol=1e-9, rtol=1e-9)
    assert not torch.allclose(g, f)  # another ground height is another motion


def test_gradients_match_central_differences():
    """Directional derivatives of every output along random directions of x and F:
    autograd against central differences (float64)."""
    rest = _cloud(n=40, seed=3)
    scene = MotionScene(rest=rest, ground=0.0, gravity=(0.0, 0.0, -9.8))
    gen = torch.Generator().manual_seed(1)
    x = rest + 0.01 * torch.randn(3, 40, 3, generator=gen, dtype=torch.float64)
    F = torch.eye(3, dtype=torch.float64) + 0.05 * torch.randn(
        3, 40, 3, 3, generator=gen, dtype=torch.float64
    )
    t = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)

    def fn(x_, F_):
        return clip_features(x_, F_, t, scene, num_frames=7)

    base = fn(x, F)
    assert base.shape == (7, len(FEATURE_NAMES))
    for k in range(4):
        dx = torch.randn(x.shape, generator=gen, dtype=torch.float64) * 0.01
        dF = torch.randn(F.shape, generator=gen, dtype=torch.float64) * 0.01
        w = torch.randn(base.shape, generator=gen, dtype=torch.float64)
        xg, Fg = x.clone().requires_grad_(), F.clone().requires_grad_()
        (fn(xg, Fg) * w).sum().backward()
        analytic = float((xg.grad * dx).sum() + (Fg.grad * dF).sum())
        h = 1e-5
        numeric = float(((fn(x + h * dx, F + h * dF) - fn(x - h * dx, F - h * dF)) * w).sum()) / (
            2 * h
        )
        assert analytic == pytest.approx(numeric, rel=1e-5, abs=1e-8), k


def test_polar_rotation_is_the_svd_rotation_and_handles_isotropy():
    gen = torch.Generator().manual_seed(4)
    M = torch.randn(5, 3, 3, generator=gen, dtype=torch.float64)
    M = M * torch.linalg.det(M).sign()[:, None, None]  # proper (det > 0)
    u, _, vt = torch.linalg.svd(M)
    torch.testing.assert_close(polar_rotation(M), u @ vt, atol=1e-9, rtol=0)
    # an isotropic M (repeated singular values) has a finite gradient
    R0 = _rot_z(0.3)
    M2 = (2.0 * R0).requires_grad_()
    polar_rotation(M2).sum().backward()
    assert torch.isfinite(M2.grad).all()


def test_clip_features_puts_the_rest_first_and_resamples_in_time():
    rest = _cloud(n=50)
    scene = MotionScene(rest=rest, ground=0.0)
    T = 9
    drop = torch.linspace(0.0, 0.16, T, dtype=torch.float64)
    x = torch.stack([rest - torch.tensor([0.0, 0.0, float(d)], dtype=torch.float64) for d in drop])
    F = torch.eye(3, dtype=torch.float64).expand(T, 50, 3, 3)
    t = torch.arange(T, dtype=torch.float64) * 0.1
    full = clip_features(x[1:], F[1:], t[1:], scene, num_frames=T)
    # every second frame observed: linear motion, so the same grid values
    sub = clip_features(x[2::2], F[2::2], t[2::2], scene, num_frames=T)
    torch.testing.assert_close(sub, full, atol=1e-9, rtol=0)
    c0z = float(rest[:, 2].mean())
    assert full[0, IDX["height"]] == pytest.approx(1.0)
    assert full[-1, IDX["height"]] == pytest.approx(1.0 - 0.16 / c0z)


def test_the_last_frame_reads_the_measures_the_captions_are_written_from():
    """Channels 13-18 on a hand-made bounce with a wobbling squash: their last frame equals
    ``motion_measures`` of the same trajectory (the captions' rebound from the first
    impact, peak shape change, flattest extent, widest spread, wobble count), and the
    speed channel is the Froude speed of the position differences."""
    from motionphysics.priors.motion_data import motion_measures

    rest = _cloud(n=400, extent=(0.2, 0.2, 0.2), centre=(0.0, 0.0, 0.6))
    scene = MotionScene(rest=rest, ground=0.0, gravity=(0.0, 0.0, -9.8))
    c0 = rest.mean(0)
    T = 16
    t = torch.arange(T, dtype=torch.float64) * 0.05
    # centroid: falls 0.4 m by frame 5, rises 0.12 m by frame 9, falls again, settles
    h = torch.tensor([0, -.05, -.12, -.2, -.3, -.4, -.34, -.3, -.285, -.28, -.3, -.35,
                      -.4, -.4, -.4, -.4], dtype=torch.float64)  # fmt: skip
    # a vertical squash that swings: 0, 10 %, 2 %, 8 %, 3 % ... of the height
    sq = [0, 0, 0, 0, 0, 0.10, 0.02, 0.08, 0.03, 0.05, 0.04, 0.04, 0.06, 0.03, 0.03, 0.03]
    xs = []
    for k in range(T):
        s = 1.0 - sq[k]
        scale = torch.tensor([1 / math.sqrt(s), 1 / math.sqrt(s), s], dtype=torch.float64)
        xs.append((rest - c0) * scale + c0 + torch.tensor([0.0, 0.0, float(h[k])]))
    x = torch.stack(xs)
    F = torch.eye(3, dtype=torch.float64).expand(T, 400, 3, 3)
    f = frame_features(x, F, t, scene)
    v = np.gradient(x.numpy(), t.numpy(), axis=0)
    m = motion_measures({"x": x.numpy(), "v": v, "t": t.numpy()})
    assert m["rebound"] > 0.2 and m["wobble"] >= 2  # the trajectory shows what it tests
    assert float(f[-1, IDX["impact_rebound"]]) == pytest.approx(m["rebound"], rel=1e-9)
    assert float(f[-1, IDX["peak_deform"]]) == pytest.approx(
        math.log(LOG_FLOOR + m["max_deform"]), abs=1e-6
    )
    assert float(f[-1, IDX["wobbles"]]) == m["wobble"]
    # running values: no rebound before the impact, peaks never fall back
    assert float(f[:6, IDX["impact_rebound"]].abs().max()) == 0.0
    for name in ("peak_deform", "peak_spread"):
        assert bool((f[1:, IDX[name]] >= f[:-1, IDX[name]] - 1e-12).all()), name
    assert bool((f[1:, IDX["low_vertical"]] <= f[:-1, IDX["low_vertical"]] + 1e-12).all())
    assert float(f[-1, IDX["low_vertical"]]) == pytest.approx(math.log(0.9), abs=1e-9)
    assert float(f[-1, IDX["peak_spread"]]) == pytest.approx(-0.5 * math.log(0.9), abs=1e-9)
    L = float((rest.max(0).values - rest.min(0).values).max())
    step = float((x[4] - x[3]).norm(dim=-1).mean()) / 0.05
    assert float(f[4, IDX["speed"]]) == pytest.approx(
        math.log(LOG_FLOOR + step / math.sqrt(G0 * L)), rel=1e-9
    )
