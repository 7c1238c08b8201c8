"""What a rollout reports besides positions (issue 15): the ``active`` mask of particles
a ``cut`` removed (renderers hide them) and the first frame material reached each
domain wall."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from motionphysics.config import config_from_dict
from motionphysics.sim.build import build_simulation

DX = 1.0 / 32
ELASTIC = {"class": "elastic", "density": 300.0, "E": 3.0e4, "nu": 0.3}


def _ball_scene(centre, radius=0.1, walls=None):
    g = np.arange(-radius, radius + 1e-9, DX / 2)
    p = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    x = p[np.linalg.norm(p, axis=1) <= radius] + np.asarray(centre)
    scene = SimpleNamespace(
        particles=torch.tensor(x, dtype=torch.float32),
        volumes=torch.full((len(x),), (DX / 2) ** 3),
        domain_lo=torch.zeros(3),
        dx=DX,
        grid_dims=(33, 33, 33),
    )
    if walls is not None:
        scene.wall_lo, scene.wall_hi = (torch.tensor(w, dtype=torch.float32) for w in walls)
    return scene, x


def test_cut_removes_material_that_then_holds_nothing_up():
    # A ball crossed by a cut plane x = 0.5 (everything at x < 0.5 removed) over a floor.
    # Until issue 15 the removed half froze in place and the grid damping of the cut's
    # half-space held the rest of the ball in mid-air beside it.
    scene, x = _ball_scene((0.5, 0.5, 0.4))
    cfg = config_from_dict(
        {
            "sim": {"grid": 32, "frames": 10, "frame_dt": 0.02, "substeps": 20},
            "boundary_conditions": [
                {"type": "surface_collider", "point": [0, 0, 0.15], "normal": [0, 0, 1]},
                {
                    "type": "surface_collider",
                    "mode": "cut",
                    "point": [0.5, 0, 0],
                    "normal": [1, 0, 0],
                },
            ],
        }
    )
    sim = build_simulation(scene, cfg, ELASTIC)
    xs, _ = sim.run()
    res = sim.last
    assert res.active.shape == xs.shape[:2]
    removed = x[:, 0] <= 0.5
    assert 0 < removed.sum() < len(x)
    np.testing.assert_array_equal(res.active[1:, removed], 0.0)
    np.testing.assert_array_equal(res.active[:, ~removed], 1.0)
    # the remaining half falls freely until the floor: after 0.1 s by g t^2 / 2 = 4.9 cm
    drop = x[~removed, 2].mean() - xs[5, ~removed, 2].mean()
    assert drop > 0.04, drop
    # the removed half is held where it was removed (the renderer hides it)
    assert np.abs(xs[-1, removed] - xs[1, removed]).max() < 1e-6


def test_rollout_records_the_first_frame_material_reaches_a_domain_wall():
    walls = ((0.1, 0.1, 0.1), (0.9, 0.9, 0.9))
    scene, _ = _ball_scene((0.5, 0.5, 0.5), walls=walls)
    cfg = config_from_dict(
        {
            "sim": {
                "grid": 32,
                "frames": 12,
                "frame_dt": 0.02,
                "substeps": 20,
                "gravity": [0, 0, 0],
                "initial_velocity": [2.0, 0.0, 0.0],
            },
            "boundary_conditions": [{"type": "bounding_box"}],
        }
    )
    sim = build_simulation(scene, cfg, ELASTIC)
    xs, _ = sim.run()
    # the ball's surface (x = 0.6 + 1/64) travels 0.3 m to the wall x = 0.9 at 2 m/s:
    # about 0.15 s = frame 7-8; reported once
    assert [h["wall"] for h in sim.last.wall_hits] == ["x+"]
    assert 6 <= sim.last.wall_hits[0]["frame"] <= 9, sim.last.wall_hits
    assert xs[..., 0].max() <= 0.9 + 1e-5  # and the wall holds it


def _watch(dx: float = 0.1):
    from motionphysics.sim.rollout import _WallWatch

    model = SimpleNamespace(wall_box=(np.zeros(3), np.ones(3)), dx=dx, boundary=None)
    return _WallWatch(model)


def test_a_wall_the_material_starts_near_counts_only_once_it_comes_nearer():
    """Frame 0 is where the scene was placed: material that starts 0.3 cells below the top
    face and falls away has not reached it; material that starts there and rises by 0.2
    cells has (and is reported at that frame); a face first reached later counts as
    before."""
    x0 = np.array([[0.5, 0.5, 0.97], [0.5, 0.5, 0.6]])  # top 0.3 cells (dx 0.1) from z+
    on = np.ones(2)
    falling = _watch()
    for f, dz in enumerate((0.0, -0.001, -0.01, -0.05)):
        falling.check(f, x0 + [0, 0, dz], on)
    assert falling.hits == []
    rising = _watch()
    for f, dz in enumerate((0.0, 0.005, 0.02)):
        rising.check(f, x0 + [0, 0, dz], on)
    assert rising.hits == [{"frame": 2, "wall": "z+"}]
    sliding = _watch()
    for f, dx_ in enumerate((0.0, 0.2, 0.46)):  # reaches x+ (0.04 m = 0.4 cells) at frame 2
        sliding.check(f, x0 + [dx_, 0, -0.2], on)
    assert sliding.hits == [{"frame": 2, "wall": "x+"}]
