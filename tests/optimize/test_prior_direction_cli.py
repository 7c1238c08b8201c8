"""What you describe is what you simulate, through the command line: two configs that differ
only in their prompt, refined by the shipped motion prior (``optimize.prior: motion``,
``loss: lmd``, every parameter of the class refined as a user who names none gets), move
the class's visible parameter in opposite directions from the same start.

Small runs (a few hundred particles, 16 frames, 6 iterations) so each pair takes about
a minute; ``benchmarks/bench_prior_direction.py`` measures the same pairs at the issue's
size (1,500 particles, 16 iterations, 3 seeds) and BENCHMARKS.md has its ratios. Here the
claim is only the direction, which is what a user judges first: the stiff prompt ends
stiffer than the soft one, each moved its own way from the start."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from motionphysics.cli import main

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "donut.ply"

PAIRS = {
    "elastic": (
        "E",
        {"class": "elastic", "density": 1100, "E": 1.0e5, "nu": 0.3},
        "A stiff {obj} is dropped, stays rigid and bounces high off the ground",
        "A soft, wobbly {obj} is dropped, squashes and wobbles like jelly",
    ),
    "newtonian": (
        "mu",
        {"class": "newtonian", "density": 1000, "mu": 1.0, "kappa": 2.2e9},
        "Thick honey shaped like a {obj} oozes slowly over the ground",
        "Thin runny water shaped like a {obj} splashes and spreads thin",
    ),
    "foam": (
        "E",
        {"class": "foam", "density": 100, "E": 5.0e3, "nu": 0.2, "tau_Y": 1.0e5, "eta": 0.5},
        "A firm foam {obj} is dropped and keeps its shape when it lands",
        "A soft, squishy foam {obj} is dropped and squashes flat",
    ),
}

SCENES = {
    "sphere": ({"source": "builtin:sphere"}, "ball"),
    "donut": ({"source": str(REAL)}, "ring"),
}


def _config(scene: dict, material: dict, prompt: str) -> dict:
    return {
        "scene": {**scene, "scale": 0.3, "translate": [0, 0, 0.3], "max_particles": 500},
        "prompt": prompt,
        "material": dict(material),
        "sim": {"grid": 20, "frames": 16, "frame_dt": 0.05, "substeps": "auto"},
        "boundary_conditions": [
            {
                "type": "surface_collider",
                "point": [0, 0, 0],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": 0.5,
            },
            {"type": "bounding_box"},
        ],
        "camera": {"width": 32, "height": 32},
        "optimize": {"prior": "motion", "loss": "lmd", "iterations": 6, "seed": 0},
    }


@pytest.mark.slow
@pytest.mark.parametrize(
    ("cls", "scene"),
    [("elastic", "sphere"), ("newtonian", "sphere"), ("foam", "donut")],
)
def test_opposite_prompts_move_the_parameter_opposite_ways(tmp_path, cls, scene):
    if scene == "donut" and not REAL.is_file():
        pytest.skip(f"real capture {REAL} not present")
    name, start, up, down = PAIRS[cls]
    source, noun = SCENES[scene]
    ends = {}
    for side, prompt in (("up", up), ("down", down)):
        cfg = tmp_path / f"{side}.yaml"
        cfg.write_text(yaml.safe_dump(_config(source, start, prompt.format(obj=noun))))
        out = tmp_path / side
        assert main(["--quiet", "run", str(cfg), "--out", str(out)]) == 0
        params = json.loads((out / "params.json").read_text())
        assert params["optimise"]["prior"] == "motion"
        assert name in params["optimise"]["optimised"]
        ends[side] = params["params"][name]
    # each moved at least 10 % its own way (measured on 2026-12-04: E 1e5 -> 1.78e5 /
    # 5.85e4, mu 1 -> 2.09 / 0.49, foam E 5e3 -> 6.29e3 / 4.09e3)
    assert ends["up"] > 1.1 * start[name], ends
    assert ends["down"] < start[name] / 1.1, ends
