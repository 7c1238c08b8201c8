"""Nothing sinks into a collider plane or a domain wall (issue 15).

An elastic cube, sand and water are dropped on a floor collider at z = 0, in a fitted
domain and in a domain whose floor is the ground: the lowest particle is never more
than 0.1 dx below the floor, and at the end (resting) it is within 0.6 dx above it.
Before the fix material settled ~0.45 dx into a floor (the grid condition acts on
nodes) and a floor on the domain's lower face was shadowed by the padding cells (the
object rested ~2.3 cells above it).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from motionphysics.config import config_from_dict
from motionphysics.scene.gaussians import GaussianScene
from motionphysics.scene.prepare import prepare
from motionphysics.sim import build_simulation

MATERIALS = {
    "elastic": {"class": "elastic", "density": 200.0, "E": 3.0e4, "nu": 0.3},
    "sand": {"class": "sand", "density": 1600.0, "E": 2.0e5, "nu": 0.3, "theta_fric": 30.0},
    "water": {"class": "newtonian", "density": 1000.0, "mu": 0.1, "kappa": 2.0e5},
}
FLOOR = {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "frictional"}


def cube_splats(side=0.3, n=8, z0=0.05) -> GaussianScene:
    """n^3 splats filling a cube of ``side`` [m] whose bottom is ``z0`` above the ground."""
    g = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n
    means = (g - 0.5) * side + np.array([0.0, 0.0, z0 + side / 2])
    N = len(means)
    return GaussianScene.from_activated(
        torch.tensor(means, dtype=torch.float32),
        torch.full((N, 3), 0.6 * side / n),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(N, 1),
        torch.full((N,), 0.9),
        torch.full((N, 3), 0.5),
    )


def drop(material: str, domain, grid: int, bcs=(FLOOR,), frames: int = 40):
    cfg = config_from_dict(
        {
            "scene": {"source": "test", "fill": True},
            "sim": {
                "grid": grid,
                "frames": frames,
                "frame_dt": 0.02,
                "substeps": "auto",
                "domain": domain,
            },
            "boundary_conditions": list(bcs),
        }
    )
    scene = prepare(cube_splats(), cfg.scene, cfg.sim, list(cfg.boundary_conditions))
    sim = build_simulation(scene, cfg, MATERIALS[material])
    xs, _ = sim.run()
    return xs, scene.dx


@pytest.mark.parametrize("material", sorted(MATERIALS))
@pytest.mark.parametrize(
    "domain, grid",
    [(None, 24), ([[-1.0, -1.0, 0.0], [1.0, 1.0, 1.0]], 48)],
    ids=["fitted", "floor"],
)
def test_dropped_material_rests_on_the_floor(material, domain, grid):
    xs, dx = drop(material, domain, grid)
    lowest = xs[:, :, 2].min(axis=1) / dx  # [dx] per frame
    assert lowest.min() >= -0.1, lowest
    # at rest on the floor: the lowest particle within 0.6 dx above it (a resting elastic
    # body keeps its half particle spacing, 0.45 dx here, between particle and floor)
    assert 0.0 - 0.1 <= lowest[-1] <= 0.6, lowest
    assert lowest[0] > 1.0  # it was dropped from above


@pytest.mark.parametrize("material", ["elastic", "water"])
def test_domain_floor_without_collider_is_a_wall(material):
    # The domain's lower face alone (a bounding box) holds the material at z = 0.
    bcs = [{"type": "bounding_box"}]
    xs, dx = drop(material, [[-1.0, -1.0, 0.0], [1.0, 1.0, 1.0]], 48, bcs=bcs, frames=30)
    lowest = xs[:, :, 2].min(axis=1) / dx
    assert lowest.min() >= -0.1 and lowest[-1] <= 0.6, lowest
    # and never beyond the side walls either
    assert np.abs(xs[..., :2]).max() <= 1.0 + 0.1 * dx


def test_fitted_domain_leaves_room_for_a_ball_thrown_sideways():
    # 2 m/s sideways for 0.44 s (0.88 m): the fitted domain (domain: null) follows the
    # motion the config implies, so the cube slides along the floor without meeting a
    # wall (until issue 15 the walls stood 0.1-0.2 m from the object).
    cfg = config_from_dict(
        {
            "scene": {"source": "test"},
            "sim": {
                "grid": 32,
                "frames": 12,
                "frame_dt": 0.04,
                "substeps": "auto",
                "initial_velocity": [2.0, 0.0, 0.0],
            },
            "boundary_conditions": [dict(FLOOR, mode="slip")],
        }
    )
    scene = prepare(cube_splats(), cfg.scene, cfg.sim, list(cfg.boundary_conditions))
    assert float(scene.wall_hi[0]) > float(scene.particles[:, 0].max()) + 0.88
    sim = build_simulation(scene, cfg, MATERIALS["elastic"])
    xs, _ = sim.run()
    assert sim.last.wall_hits == []
    assert xs[-1, :, 0].mean() - xs[0, :, 0].mean() > 0.7  # it really travelled


def test_fitted_domain_grows_for_a_fluid_spreading():
    from motionphysics.scene.prepare import motion_extent

    cfg = config_from_dict({"sim": {"frames": 25, "frame_dt": 0.04}})
    lo, hi = motion_extent(cfg.sim, material_class="newtonian", height=0.3)
    np.testing.assert_allclose(hi[:2], 0.9) and np.testing.assert_allclose(lo[:2], -0.9)
    lo_s, hi_s = motion_extent(cfg.sim, [], [FLOOR], material_class="elastic", height=0.3)
    np.testing.assert_allclose(hi_s[:2], 0.0)
    assert lo_s[2] == pytest.approx(-0.5 * 9.8 * 0.96**2, rel=0.02)  # the fall (to the floor)
    assert motion_extent(cfg.sim)[0][2] == 0.0  # no floor: the domain's wall is the floor
    # an impulse is a velocity change at its start
    f = [{"type": "add_impulse", "force": [1.0, 0.0, 0.0], "start": 0.5}]
    lo_i, hi_i = motion_extent(cfg.sim, forces=f)
    assert hi_i[0] == pytest.approx(0.46, rel=0.02)
