"""A simile names what a thing is simulated as: "a duck creeps out slowly like syrup" is a
syrupy duck, through ``motionphysics run`` with a config file, as a user writes it. A
material the sentence names for the thing itself still wins ("a rubber duck ... like
syrup" is rubber), and a substance behind a preposition without "like" stays scenery."""

from __future__ import annotations

import json

import pytest
import yaml

from motionphysics.cli import main


def _run(tmp_path, capsys, prompt: str) -> tuple[dict, str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "scene": {
                    "source": "builtin:duck",
                    "scale": 0.3,
                    "translate": [0, 0, 0.3],
                    "max_particles": 400,
                },
                "prompt": prompt,
                "sim": {"grid": 16, "frames": 4, "frame_dt": 0.04, "substeps": "auto"},
                "camera": {"width": 32, "height": 32},
            }
        )
    )
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    return json.loads((out / "params.json").read_text()), capsys.readouterr()


@pytest.mark.parametrize(
    ("prompt", "cls"),
    [
        ("A duck creeps out slowly like syrup", "newtonian"),
        ("A rubber duck creeps like syrup", "elastic"),
    ],
)
def test_a_simile_names_the_material_of_a_shape(tmp_path, capsys, prompt, cls):
    params, captured = _run(tmp_path, capsys, prompt)
    assert params["class"] == cls
    assert "not sure" not in captured.out + captured.err
