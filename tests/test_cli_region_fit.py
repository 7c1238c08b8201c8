"""``fit`` through the static collider of a region run (issue 25): a ball cut out of a
scene with a table of splats bounces on the table (no collider plane in the config); its
trajectory, made by ``motionphysics simulate``, is fitted from a start 3x too stiff, so
the gradients cross the static scene's level set every substep of contact."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import yaml

from motionphysics.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parent / "scene"))
from test_scene_region import _slab_and_ball  # noqa: E402


def test_fit_recovers_stiffness_of_a_ball_bouncing_on_static_splats(tmp_path):
    from motionphysics.scene.ply import write_ply

    write_ply(_slab_and_ball(), tmp_path / "table.ply")
    cfg = {
        "scene": {
            "source": str(tmp_path / "table.ply"),
            "region": {"sphere": [[0.0, 0.0, 0.105], 0.12]},
            "max_particles": 800,
        },
        "prompt": "A rubber ball bounces on the table.",
        "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
        "sim": {
            "grid": 16,
            "frames": 8,
            "frame_dt": 0.04,
            "substeps": 36,
            "initial_velocity": [0.0, 0.0, 0.5],
        },
        "camera": {"width": 32, "height": 32},
        "optimize": {"iterations": 3},
    }
    truth = tmp_path / "truth.yaml"
    truth.write_text(yaml.safe_dump(cfg, sort_keys=False))
    assert main(["simulate", str(truth), "--out", str(tmp_path / "ref"), "--quiet"]) == 0
    cfg["material"]["E"] = 3.0e5
    start = tmp_path / "start.yaml"
    start.write_text(yaml.safe_dump(cfg, sort_keys=False))
    ref = tmp_path / "ref" / "trajectory.npz"
    out = tmp_path / "fit"
    assert main(["fit", str(start), "--reference", str(ref), "--out", str(out), "--quiet"]) == 0
    params = json.loads((out / "params.json").read_text())
    assert params["params"]["E"] == pytest.approx(1.0e5, rel=0.1)
    run_yaml = yaml.safe_load((out / "run.yaml").read_text())
    assert run_yaml["boundary_conditions"] == []  # held by the static scene only
