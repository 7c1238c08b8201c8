"""The run config (the README's config reference): validation messages, unknown keys, round trip."""

from __future__ import annotations

import pytest
import yaml

from motionphysics.config import config_from_dict, dump_config, load_config
from motionphysics.errors import UserInputError


def test_defaults_follow_design_md():
    cfg = config_from_dict({})
    assert cfg.scene.source == "builtin:sphere"
    assert cfg.sim.grid == 64 and cfg.sim.frames == 48 and cfg.sim.substeps == 64
    assert cfg.sim.gravity == (0.0, 0.0, -9.8)
    assert cfg.optimize.boost == 8 and cfg.optimize.grad_mode == "full"


@pytest.mark.parametrize(
    "data, where",
    [
        ({"scen": {}}, "scen: unknown key"),
        ({"sim": {"grid": "x"}}, "sim.grid:"),
        ({"sim": {"substeps": 0}}, "sim.substeps"),
        (
            {"boundary_conditions": [{"type": "surface_collider", "mdoe": 1}]},
            "boundary_conditions[0].mdoe: unknown key",
        ),
        (
            {
                "forces": [
                    {
                        "type": "add_impulse",
                        "force": [0, 0, 1],
                        "box": [[0, 0, 0], [1, 1, 1]],
                        "sphere": [[0, 0, 0], 1],
                    }
                ]
            },
            "forces[0]",
        ),
        ({"material": {"class": "rubbery"}}, "material.class"),
        ({"scene": {"crop": [1, 0, 0, 1, 0, 1]}}, "scene"),
    ],
)
def test_errors_name_the_file_and_field(data, where):
    with pytest.raises(UserInputError) as err:
        config_from_dict(data, "cfg.yaml")
    msg = str(err.value)
    assert msg.startswith("cfg.yaml: ") and where in msg and "\n" not in msg


def test_round_trip_including_sticky_collider(tmp_path):
    # A resolved config (run.yaml) must load back equal; a sticky collider's friction
    # stays "absent" (null) so re-validation does not invent a friction.
    cfg = config_from_dict(
        {
            "material": {"class": "elastic", "E": 1e6, "nu": 0.3},
            "boundary_conditions": [
                {"type": "surface_collider", "mode": "sticky"},
                {
                    "type": "surface_collider",
                    "point": [0, 0, -1],
                    "mode": "frictional",
                    "friction": 0.5,
                },
                {"type": "bounding_box"},
            ],
            "forces": [{"type": "add_impulse", "force": [0, 0, 5], "end": 0.01}],
        }
    )
    path = tmp_path / "run.yaml"
    path.write_text(dump_config(cfg))
    again = load_config(path)
    assert again == cfg
    assert again.boundary_conditions[0].friction is None
    assert yaml.safe_load(path.read_text())["material"]["class"] == "elastic"


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(UserInputError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("scene: [unclosed\n")
    with pytest.raises(UserInputError, match="not valid YAML"):
        load_config(bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(UserInputError, match="mapping"):
        load_config(top)
