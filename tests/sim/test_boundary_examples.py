"""The example run configs (examples/*.yaml): they load, their boundary programs build on
the prepared scenes, and (slow) each simulates to the end with the behaviour it promises.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from motionphysics.config import MATERIAL_CLASSES, SurfaceCollider, load_config

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
OWN = sorted(p for p in EXAMPLES.glob("*.yaml") if p.name != "demo.yaml")


def kb_estimate(cfg):
    """The offline estimate from the prompt (what `run` and `simulate` use when the config
    leaves the class out), or None when the config names the class."""
    if cfg.material.class_ is not None:
        return None
    from motionphysics.assembly import estimate_material

    return estimate_material(cfg.prompt, None, "kb")


def test_there_is_an_example_per_material_class():
    classes = set()
    for p in OWN:
        cfg = load_config(p)
        est = kb_estimate(cfg)
        classes.add(cfg.material.class_ if est is None else est["class"])
    assert classes == set(MATERIAL_CLASSES)


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.yaml")), ids=lambda p: p.name)
def test_example_loads_and_has_a_ground(path):
    cfg = load_config(path)
    grounds = [
        bc
        for bc in cfg.boundary_conditions
        if isinstance(bc, SurfaceCollider)
        and tuple(bc.point) == (0.0, 0.0, 0.0)
        and tuple(bc.normal) == (0.0, 0.0, 1.0)
        and bc.mode != "cut"
    ]
    assert grounds, "each example stands on a ground collider at z = 0"
    assert cfg.scene.source.startswith("builtin:")


@cache
def prepared(path: Path):
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare

    cfg = load_config(path)
    return cfg, prepare(
        load_scene(cfg.scene.source), cfg.scene, cfg.sim, list(cfg.boundary_conditions)
    )


@pytest.mark.parametrize("path", OWN, ids=lambda p: p.name)
def test_example_boundary_program_builds_on_its_scene(path):
    from motionphysics.sim.boundary import BoundaryProgram

    cfg, scene = prepared(path)
    prog = BoundaryProgram.build(
        cfg.boundary_conditions,
        cfg.forces,
        x0=scene.particles,
        domain_lo=scene.domain_lo.numpy(),
        dx=scene.dx,
        grid_dims=scene.grid_dims,
    )
    for i, force in enumerate(cfg.forces):
        n = prog.selected[f"forces[{i}]"]
        # a region selection is a real part of the object, not all of it by accident
        if force.box is not None or force.sphere is not None:
            assert 0 < n < len(scene.particles)


def simulate(path: Path):
    """Full forward run as `motionphysics simulate` does it (material from the config)."""
    from motionphysics.pipeline import _map_to_sim, resolve_material
    from motionphysics.sim import build_simulation

    cfg, scene = prepared(path)
    material = resolve_material(cfg, kb_estimate(cfg))["material"]
    sim_values, _ = _map_to_sim(material, cfg, scene)
    sim = build_simulation(scene, cfg, {"class": material.cls, **sim_values}, "cpu")
    xs, _ = sim.run(cfg.sim.frames)
    return cfg, scene, sim, xs


@pytest.mark.slow
@pytest.mark.parametrize("path", OWN, ids=lambda p: p.name)
def test_example_runs_to_the_end_with_its_behaviour(path):
    cfg, scene, sim, xs = simulate(path)
    x0 = scene.particles.numpy()
    dx = scene.dx
    assert np.isfinite(xs).all()
    # grid contact lets particles sink at most about half a cell into the ground
    assert xs[..., 2].min() > -0.75 * dx
    name = path.stem
    z = xs[..., 2]
    height = z.max(axis=1) - z.min(axis=1)
    if name == "elastic_ball":
        centre = z.mean(axis=1)
        k = int(np.argmin(centre))
        assert k < len(centre) - 1 and centre[k:].max() > centre[k] + 0.02, "the ball bounces"
    elif name == "metal_rod":
        held = x0[:, 0] <= -0.21
        np.testing.assert_allclose(xs[-1][held], x0[held], atol=1e-5)  # the clamped end
        tip = x0[:, 0] >= 0.25
        drop = x0[tip, 2].mean() - xs[-1][tip, 2].mean()
        assert drop > 0.05, "the free end is bent down and stays down"
    elif name == "plasticine_blob":
        assert height[-1] < 0.75 * height[0], "squashed"
        assert abs(height[-1] - height[-5]) < 0.1 * height[0], "keeps its new shape"
    elif name in (
        "sand_column",
        "newtonian_dam_break",
        "newtonian_droplet",
        "non_newtonian_toothpaste",
    ):
        # collapses / splashes / piles up: the centre comes down and the footprint widens
        # (measured: centre height / 6 to / 20, 95th-percentile radius x 2.4 to x 3.7)
        centre = z.mean(axis=1)
        assert centre[-1] < 0.5 * centre[0]

        def r95(x):
            return np.percentile(np.linalg.norm(x[:, :2] - x[:, :2].mean(axis=0), axis=1), 95)

        assert r95(xs[-1]) > 1.5 * r95(xs[0])
    elif name == "foam_cube":
        centre = z.mean(axis=1)
        assert centre[-1] < centre[0] - 0.1, "it fell and stays on the ground"
