"""prepare(): transform order, filters, anisotropy, fill, volumes, downsampling, domain."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motionphysics.config import SceneConfig, SimConfig, SurfaceCollider
from motionphysics.errors import UserInputError
from motionphysics.scene import GaussianScene, load_scene, prepare
from motionphysics.scene.prepare import PAD_CELLS
from motionphysics.scene.sh import eval_sh

GROUND = [SurfaceCollider(type="surface_collider", point=(0, 0, 0), normal=(0, 0, 1))]


@pytest.fixture(scope="module")
def sphere():
    return load_scene("builtin:sphere")


def _cfg(**kw):
    kw.setdefault("source", "test")
    kw.setdefault("max_particles", 10**7)
    return SceneConfig(**kw)


def small_scene(n=6, degree=0, seed=0):
    g = torch.Generator().manual_seed(seed)
    return GaussianScene(
        means=torch.randn(n, 3, generator=g, dtype=torch.float64).float() * 0.3,
        log_scales=math.log(0.02) + 0.5 * torch.randn(n, 3, generator=g),
        quats=torch.randn(n, 4, generator=g) * 2,
        logit_opacities=torch.full((n,), 3.0),
        sh=torch.randn(n, (degree + 1) ** 2, 3, generator=g),
    )


def test_transform_order_scale_rotate_translate():
    s = small_scene(degree=3)
    rot = [("z", 90.0), ("x", 30.0)]
    cfg = _cfg(scale=2.0, rotate=rot, translate=(1.0, 2.0, 3.0), fill=False, max_anisotropy=1e6)
    out = prepare(s, cfg, SimConfig(grid=16))
    # Reference: scipy, extrinsic rotations applied in list order (z first, then x).
    r = Rotation.from_euler("zx", [90, 30], degrees=True).as_matrix()
    want = 2.0 * s.means.double().numpy() @ r.T + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(
        out.splats.means.double().numpy(), want, atol=1e-6
    )  # float32 of O(1)
    wrong = (
        2.0
        * s.means.double().numpy()
        @ Rotation.from_euler("xz", [30, 90], degrees=True).as_matrix().T
    )
    assert np.abs(out.splats.means.double().numpy() - (wrong + [1, 2, 3])).max() > 0.01
    # Orientation: new axes = R @ old axes; covariance scaled by s^2 and rotated.
    np.testing.assert_allclose(
        out.splats.rotation_matrices().double().numpy(),
        r @ s.rotation_matrices().double().numpy(),
        atol=1e-6,
    )
    cov = 4.0 * r @ s.covariances().double().numpy() @ r.T
    np.testing.assert_allclose(
        out.splats.covariances().double().numpy(), cov, rtol=1e-5, atol=1e-10
    )
    # Quaternion storage magnitude kept (unnormalised, as the input).
    np.testing.assert_allclose(
        out.splats.quats.norm(dim=1).numpy(), s.quats.norm(dim=1).numpy(), rtol=1e-6
    )
    # SH rotated with the splat: colour seen along R d equals the old colour along d.
    d = torch.nn.functional.normalize(torch.randn(s.num, 3, dtype=torch.float64), dim=-1)
    rt = torch.from_numpy(r)
    np.testing.assert_allclose(
        eval_sh(out.splats.sh.double(), d @ rt.T).numpy(),
        eval_sh(s.sh.double(), d).numpy(),
        atol=1e-5,
    )  # float32 coefficients
    np.testing.assert_allclose(out.source_to_world[:3, :3].numpy(), 2.0 * r, atol=1e-12)
    # No downsampling: each splat is its own particle.
    assert torch.equal(out.splat_parent, torch.arange(s.num))
    assert float(out.splat_offset.abs().max()) == 0.0
    torch.testing.assert_close(out.particles, out.splats.means)


def test_opacity_filter_and_crop():
    s = small_scene(n=40)
    s.logit_opacities[:10] = -10.0  # opacity ~4.5e-5
    out = prepare(s, _cfg(opacity_threshold=0.02, fill=False), SimConfig(grid=16))
    assert out.splats.num == 30
    crop = (-0.1, 10.0, -10.0, 10.0, -10.0, 10.0)
    out = prepare(s, _cfg(opacity_threshold=0.02, crop=crop, fill=False), SimConfig(grid=16))
    want = (s.means[10:, 0] >= -0.1).sum()
    assert out.splats.num == int(want) and bool((out.splats.means[:, 0] >= -0.1).all())
    # The crop is in the world frame: after the translation.
    out = prepare(
        s,
        _cfg(translate=(5, 0, 0), crop=(4.9, 10, -10, 10, -10, 10), fill=False),
        SimConfig(grid=16),
    )
    assert out.splats.num == int((s.means[10:, 0] >= -0.1).sum())


def test_anisotropy_cap():
    s = small_scene(n=3)
    s.log_scales = torch.log(torch.tensor([[1.0, 0.01, 0.001], [0.5, 0.4, 0.3], [0.002, 0.2, 0.1]]))
    out = prepare(s, _cfg(max_anisotropy=4.0, fill=False), SimConfig(grid=16))
    np.testing.assert_allclose(
        out.splats.scales.numpy(), [[1.0, 0.25, 0.25], [0.5, 0.4, 0.3], [0.05, 0.2, 0.1]], rtol=1e-6
    )
    sc = load_scene("builtin:sphere")
    out = prepare(sc, _cfg(max_anisotropy=3.0, fill=False), SimConfig(grid=16))
    ratio = out.splats.scales.max(1).values / out.splats.scales.min(1).values
    assert float(ratio.max()) <= 3.0 * (1 + 1e-5)


def test_fill_closed_sphere_inside_only_and_volume(sphere):
    out = prepare(sphere, _cfg(translate=(0, 0, 1)), SimConfig(grid=64), GROUND)
    assert out.n_interior > 1000
    fill = out.particles[out.n_visible :].double()
    r = (fill - torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).norm(dim=1)
    assert float(r.max()) < 0.5  # all strictly inside the sphere of radius 0.5
    # Fill points sit at cell centres of the simulation grid.
    frac = ((fill - out.domain_lo.double()) / out.dx) % 1.0
    np.testing.assert_allclose(frac.numpy(), 0.5, atol=1e-4)
    vol = float(out.volumes.double().sum())
    assert abs(vol - math.pi / 6) < 0.1 * math.pi / 6
    assert abs(out.total_volume - vol) < 1e-4 * vol
    assert bool((out.volumes > 0).all())


def test_fill_off_and_open_surface_add_nothing(sphere):
    out = prepare(sphere, _cfg(fill=False), SimConfig(grid=48))
    assert out.n_interior == 0 and out.n_particles == sphere.num
    # An open hemisphere has no enclosed cells.
    half = sphere.subset(sphere.means[:, 2] > 0.05)
    out = prepare(half, _cfg(), SimConfig(grid=48))
    assert out.n_interior == 0
    assert float(out.volumes.sum()) > 0


def test_cube_volume(sphere):
    cube = load_scene("builtin:cube")
    out = prepare(cube, _cfg(scale=0.5), SimConfig(grid=48))
    assert abs(float(out.volumes.double().sum()) - 0.125) < 0.1 * 0.125


def test_downsampling_keeps_every_splat_attached(sphere):
    full = prepare(sphere, _cfg(), SimConfig(grid=48))
    out = prepare(sphere, _cfg(max_particles=1500), SimConfig(grid=48))
    assert out.n_particles == 1500 and full.n_particles > 1500
    assert 0 < out.n_interior < 1500
    parent = out.splat_parent
    assert parent.dtype == torch.int64 and parent.shape == (sphere.num,)
    assert int(parent.min()) >= 0 and int(parent.max()) < out.n_particles
    torch.testing.assert_close(
        out.particles[parent] + out.splat_offset, out.splats.means, atol=1e-6, rtol=0
    )
    # Parent = nearest kept particle (brute force, float64).
    d = torch.cdist(out.splats.means.double(), out.particles.double())
    nearest = d.min(dim=1).values
    np.testing.assert_allclose(
        d[torch.arange(sphere.num), parent].numpy(), nearest.numpy(), atol=1e-7
    )
    # Mass is conserved by downsampling.
    assert abs(float(out.volumes.double().sum()) - float(full.volumes.double().sum())) < 1e-5


def test_fitted_domain_contains_particles_and_ground(sphere):
    sim = SimConfig(grid=40)
    out = prepare(sphere, _cfg(scale=0.2, translate=(0.3, -0.2, 1.5)), sim, GROUND)
    lo, hi, dx = out.domain_lo.double(), out.domain_hi.double(), out.dx
    nodes = torch.tensor(out.grid_dims, dtype=torch.float64)
    torch.testing.assert_close(hi, lo + (nodes - 1) * dx)
    assert abs((hi - lo).max().item() - sim.grid * dx) < 1e-5 * dx * sim.grid
    assert out.grid_dims[int((hi - lo).argmax())] == sim.grid + 1
    p = out.particles.double()
    assert bool((p.min(0).values >= lo + PAD_CELLS * dx - 1e-6).all())
    assert bool((p.max(0).values <= hi - PAD_CELLS * dx + 1e-6).all())
    # The ground plane z=0 is inside with at least 3 cells below it.
    assert float(lo[2]) <= -PAD_CELLS * dx + 1e-6
    # Expanded by half the object's extent (0.2) beyond the particles in x.
    assert float(p[:, 0].min() - lo[0]) >= 0.1 - 1e-6


def test_given_domain(sphere):
    # sim.domain is the box material may occupy: its faces are the walls and the solver's
    # PAD_CELLS (+ half a cell, prepare.WALL_PHASE) lie OUTSIDE it. (Until issue 15 the
    # padding was taken from inside the box: domain_lo was -1 and 31 nodes spanned z.)
    dom = ((-1.0, -1.0, -1.0), (1.0, 1.0, 2.0))
    out = prepare(sphere, _cfg(), SimConfig(grid=30, domain=dom))
    dx = out.dx
    assert dx == pytest.approx(3.0 / 30)
    np.testing.assert_allclose(out.wall_lo.numpy(), [-1, -1, -1], atol=1e-6)
    np.testing.assert_allclose(out.wall_hi.numpy(), [1, 1, 2], atol=1e-6)
    np.testing.assert_allclose(out.domain_lo.numpy(), -1 - (PAD_CELLS + 0.5) * dx, atol=1e-6)
    assert bool((out.domain_hi >= out.wall_hi + PAD_CELLS * dx - 1e-6).all())
    assert out.grid_dims == (28, 28, 38)
    with pytest.raises(UserInputError, match="sim.domain"):
        prepare(sphere, _cfg(translate=(0.8, 0, 0)), SimConfig(grid=30, domain=dom))


def test_domain_whose_floor_is_the_ground_is_valid(sphere):
    # An object resting on the ground z = 0 in a domain starting at the ground (how a
    # person writes it) is accepted; the ground plane and the walls sit half-way between
    # grid nodes (prepare.WALL_PHASE), with the padding below the floor.
    dom = ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0))
    scene = _cfg(scale=0.3, translate=(0.0, 0.0, 0.15))
    out = prepare(sphere, scene, SimConfig(grid=32, domain=dom), GROUND)
    assert float(out.particles[:, 2].min()) >= -1e-6
    phase = ((0.0 - out.domain_lo.double()) / out.dx) % 1.0
    np.testing.assert_allclose(phase.numpy(), 0.5, atol=1e-5)
    assert float(out.wall_lo[2]) == pytest.approx(0.0, abs=1e-6)
    # fitted: the ground is half-way between nodes too, the walls inside the padding
    fit = prepare(sphere, scene, SimConfig(grid=32), GROUND)
    phase = float(((0.0 - fit.domain_lo[2].double()) / fit.dx) % 1.0)
    assert phase == pytest.approx(0.5, abs=1e-4)
    assert bool((fit.wall_lo >= fit.domain_lo + PAD_CELLS * fit.dx - 1e-6).all())
    assert bool((fit.wall_hi <= fit.domain_hi - PAD_CELLS * fit.dx + 1e-6).all())


def test_empty_after_filtering_is_a_user_error(sphere):
    with pytest.raises(UserInputError) as e:
        prepare(sphere, _cfg(opacity_threshold=0.95), SimConfig())
    assert "opacity_threshold" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(UserInputError, match="crop"):
        prepare(sphere, _cfg(crop=(5, 6, 5, 6, 5, 6)), SimConfig())
    with pytest.raises(UserInputError):
        prepare(sphere.subset(torch.zeros(sphere.num, dtype=torch.bool)), _cfg(), SimConfig())


def test_degenerate_splats_do_not_hang():
    # One splat, a huge one, a needle and a pancake: bounded work, finite outputs.
    s = small_scene(n=4)
    s.log_scales = torch.tensor(
        [[-30.0, -30.0, -30.0], [30.0, 30.0, 30.0], [0.0, -40.0, -40.0], [-40.0, 1.0, 1.0]]
    )
    out = prepare(s, _cfg(max_anisotropy=1e9), SimConfig(grid=64))
    assert torch.isfinite(out.particles).all() and torch.isfinite(out.volumes).all()
    one = prepare(s.subset([0]), _cfg(), SimConfig(grid=16))
    assert one.n_particles >= 1 and one.dx > 0 and float(one.volumes.sum()) > 0


def test_stratified_subset_covers_space():
    from motionphysics.scene.prepare import stratified_subset

    rng = np.random.default_rng(0)
    # A dense blob and a sparse far-away tail: a random 5% subset often misses the tail.
    pts = np.concatenate([rng.normal(size=(20000, 3)) * 0.1, np.linspace([2, 0, 0], [3, 0, 0], 30)])
    idx = stratified_subset(pts, 1000, np.random.default_rng(1))
    assert len(idx) == 1000 and len(np.unique(idx)) == 1000 and np.all(np.diff(idx) > 0)
    tail = idx[idx >= 20000]
    assert len(tail) >= 5
    d = torch.cdist(torch.from_numpy(pts[20000:]), torch.from_numpy(pts[idx])).min(dim=1).values
    assert float(d.max()) < 0.5  # every tail point has a kept point within its cube size
    np.testing.assert_array_equal(stratified_subset(pts[:10], 20, rng), np.arange(10))


DONUT = (
    __import__("pathlib").Path(__file__).resolve().parents[2].parent
    / "shared"
    / "data"
    / "real"
    / "donut.ply"
)


@pytest.mark.skipif(not DONUT.is_file(), reason=f"real capture not present at {DONUT}")
def test_prepare_real_donut():
    """A real capture: scaled to ~1 m, stood on the ground, downsampled to 8000 particles."""
    d = load_scene(str(DONUT))
    cfg = _cfg(scale=5.0, rotate=[("x", 90.0)], translate=(0, 0, 0.8), max_particles=8000)
    out = prepare(d, cfg, SimConfig(grid=48), GROUND)
    assert out.n_particles == 8000
    assert torch.isfinite(out.particles).all() and bool((out.volumes > 0).all())
    torch.testing.assert_close(
        out.particles[out.splat_parent] + out.splat_offset, out.splats.means, atol=1e-6, rtol=0
    )
    # Every splat follows a particle within a few cells (even downsampling, no far parents).
    assert float(out.splat_offset.norm(dim=1).max()) < 3 * out.dx
    # Occupied volume of a ~1 m donut: between a thin shell and its bounding box.
    lo, hi = out.splats.means.min(0).values, out.splats.means.max(0).values
    box = float((hi - lo).prod())
    assert 0.1 * box < float(out.volumes.sum()) < box
    assert float(out.domain_lo[2]) <= -PAD_CELLS * out.dx + 1e-6
