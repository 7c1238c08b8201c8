"""Prompts for different materials on the same scene give measurably different motion.

The prompts go through the real path (kb estimate -> config merge and clamps -> sim map
-> simulate); the statistics are those of metrics.json (final height over initial
height, spread ratio, rebound ratio).
"""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.config import config_from_dict
from motionphysics.metrics.physical import physical_metrics

PROMPTS = {
    "elastic": "A rubber ball is dropped onto the ground and bounces back.",
    "metal": "A steel ball is dropped onto the ground.",
    "water": "A blob of water is dropped onto the ground and splashes.",
    "sand": "A ball of dry sand is dropped onto the ground and collapses.",
    "toothpaste": "A blob of toothpaste is dropped onto the ground.",
}

SCENE = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.3],
        "max_particles": 1000,
    },
    "sim": {"grid": 16, "frames": 16, "frame_dt": 0.04, "substeps": "auto"},
    "boundary_conditions": [
        {
            "type": "surface_collider",
            "point": [0, 0, 0],
            "normal": [0, 0, 1],
            "mode": "frictional",
            "friction": 0.3,
        },
        {"type": "bounding_box"},
    ],
}


def _motion(names, scale: float = 0.3):
    from motionphysics.init import EstimateOptions, estimate_many
    from motionphysics.pipeline import _map_to_sim, _simulate, resolve_material
    from motionphysics.progress import Progress
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare

    data = {**SCENE, "scene": {**SCENE["scene"], "scale": scale, "translate": [0, 0, scale]}}
    cfg = config_from_dict(data)
    sim_scene = prepare(
        load_scene(cfg.scene.source), cfg.scene, cfg.sim, list(cfg.boundary_conditions)
    )
    ests = estimate_many([PROMPTS[n] for n in names], options=EstimateOptions(announce=False))
    out = {}
    for name, est in zip(names, ests, strict=True):
        res = resolve_material(
            cfg,
            {"class": est.cls, "density": est.density, "params": dict(est.values), "backend": "kb"},
        )
        sim_values, _ = _map_to_sim(res["material"], cfg, sim_scene)
        with Progress(quiet=True) as prog, prog.stage("simulate") as st:
            xs, _, vs, _ = _simulate(
                sim_scene, cfg, res["material"], sim_values, "cpu", cfg.sim.frames, st
            )
        m = physical_metrics({"x": xs, "t": np.arange(len(xs)) * cfg.sim.frame_dt, "v": vs})
        out[name] = (est.cls, m)
    return out


def _check(out):
    for name, (cls, m) in out.items():
        print(
            f"{name:10s} {cls:13s} height {m['final_height_ratio']:.3f} spread {m['spread_ratio']:.3f} "
            f"rebound {m['rebound_ratio']:.3f}"
        )
    if "elastic" in out:
        cls, m = out["elastic"]
        assert cls == "elastic"
        assert m["final_height_ratio"] > 0.85 and m["spread_ratio"] < 1.1  # keeps its shape
        assert m["rebound_ratio"] > 0.3  # and bounces
    if "metal" in out:
        cls, m = out["metal"]
        assert cls == "metal"
        assert m["final_height_ratio"] > 0.85 and m["spread_ratio"] < 1.1
        assert (
            m["rebound_ratio"]
            < out.get("elastic", (None, {"rebound_ratio": 1.0}))[1]["rebound_ratio"] - 0.2
        )
    for name in ("water", "sand", "toothpaste"):
        if name in out:
            _, m = out[name]
            assert (
                m["final_height_ratio"] < 0.5 and m["spread_ratio"] > 1.5
            )  # collapses and spreads
            assert m["rebound_ratio"] < 0.2
    if "water" in out and "sand" in out:
        # water runs out further and thinner than sand, which stops at its friction angle
        assert out["water"][1]["spread_ratio"] > out["sand"][1]["spread_ratio"] + 0.2
    assert out.get("water", ("newtonian",))[0] == "newtonian"
    assert out.get("sand", ("sand",))[0] == "sand"
    assert out.get("toothpaste", ("non_newtonian",))[0] == "non_newtonian"


def test_solids_and_fluids_separate():
    _check(_motion(["elastic", "water", "sand"]))


@pytest.mark.slow
def test_five_prompts_separate():
    _check(_motion(list(PROMPTS)))


@pytest.mark.slow
def test_toothpaste_holds_together_more_than_water():
    """At toothpaste scale (an 8 cm blob) its yield stress keeps it from running out as far
    as water. (A 30 cm blob of either flattens to the grid's resolution: both spread alike.)"""
    out = _motion(["water", "toothpaste"], scale=0.08)
    _check(out)
    assert out["water"][1]["spread_ratio"] > out["toothpaste"][1]["spread_ratio"] + 0.2
