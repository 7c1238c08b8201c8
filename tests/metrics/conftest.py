"""Two tiny simulated runs (a bouncing ball and a splashing drop), made once per session
with the real ``motionphysics simulate`` command."""

from __future__ import annotations

import pytest
import yaml

BALL = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.3],
        "max_particles": 800,
    },
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "material": {"class": "elastic", "density": 1100, "E": 1.5e7, "nu": 0.4},
    "sim": {"grid": 16, "frames": 14, "frame_dt": 0.04, "substeps": "auto"},
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
    "camera": {"width": 64, "height": 48},
    "optimize": {"prior": "none", "seed": 0},
}
DROP = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.2,
        "translate": [0, 0, 0.3],
        "max_particles": 800,
    },
    "prompt": "A drop of water falls and splashes on the ground.",
    "material": {"class": "newtonian", "density": 1000, "mu": 1.0e-3, "kappa": 2.0e9},
    "sim": {
        "domain": [[-0.8, -0.8, -0.1], [0.8, 0.8, 0.6]],
        "grid": 24,
        "frames": 11,
        "frame_dt": 0.04,
        "substeps": "auto",
    },
    "boundary_conditions": [
        {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "slip"},
        {"type": "bounding_box"},
    ],
    "camera": {"width": 64, "height": 48},
    "optimize": {"prior": "none", "seed": 0},
}


@pytest.fixture(scope="session")
def tiny_runs(tmp_path_factory):
    from motionphysics.cli import main

    root = tmp_path_factory.mktemp("eval_runs")
    out = {}
    for name, cfg in (("ball", BALL), ("drop", DROP)):
        path = root / f"{name}.yaml"
        path.write_text(yaml.safe_dump(cfg))
        assert main(["--quiet", "simulate", str(path), "--out", str(root / name)]) == 0
        out[name] = root / name
    return out
