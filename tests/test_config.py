"""The run config (the README's config reference): validation messages, unknown keys, round trip."""

from __future__ import annotations

import pytest
import yaml

from motionphysics.config import config_from_dict, dump_config, load_config
from motionphysics.errors import UserInputError


def test_defaults_follow_design_md():
    cfg = config_from_dict({})
    assert cfg.scene.source == "builtin:sphere"
    # substeps: auto (issue 23: the material is simulated as described, within the
    # budget sim.max_substeps; a fixed 64 compressed soft and slender things visibly)
    assert cfg.sim.grid == 64 and cfg.sim.frames == 48 and cfg.sim.substeps == "auto"
    assert cfg.sim.max_substeps == 2048
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


@pytest.mark.parametrize(
    "data, parts",
    [
        ({"material": {"class": "rubberish"}}, ["material.class", "'rubberish'", "'elastic'"]),
        (
            {"boundary_conditions": [{"type": "surface_collider", "mode": "glue"}]},
            ["boundary_conditions[0].mode", "'glue'", "'sticky'", "'frictional'"],
        ),
        ({"sim": {"grid": "lots"}}, ["sim.grid", "'lots'", "an integer"]),
        ({"sim": {"substeps": "lots"}}, ["sim.substeps", "'lots'", "integer", "'auto'"]),
        ({"sim": {"grid": 2}}, ["sim.grid", "got 2", ">= 8"]),
        ({"sim": {"frame": 10}}, ["sim.frame", "unknown key", "did you mean `frames`?"]),
        ({"camra": {}}, ["camra", "unknown key", "did you mean `camera`?"]),
        ({"scene": {"crop": [1, 2]}}, ["scene.crop", "[1, 2]", "6 items"]),
        ({"sim": {"gravity": [0, 0, "down"]}}, ["sim.gravity[2]", "'down'", "a number"]),
        ({"boundary_conditions": [{"type": "glue"}]}, ["boundary_conditions[0].type", "'glue'"]),
        ({"material": {"E": -5.0}}, ["material.E", "-5.0", "> 0 Pa", "physically impossible"]),
        ({"material": {"nu": 0.75}}, ["material.nu", "0.75", "nu <= 0.5"]),
        ({"material": {"density": 0}}, ["material.density", "got 0"]),
        ({"material": {"mu": -1.0}}, ["material.mu", "viscosity > 0"]),
        ({"material": {"E": float("nan")}}, ["material.E", "nan", "finite"]),
        ({"sim": {"frame_dt": float("inf")}}, ["sim.frame_dt", "inf", "finite"]),
    ],
)
def test_every_error_names_file_field_value_and_expectation(data, parts):
    with pytest.raises(UserInputError) as err:
        config_from_dict(data, "cfg.yaml")
    msg = str(err.value)
    assert msg.startswith("cfg.yaml: ") and "\n" not in msg, msg
    for p in parts:
        assert p in msg, (p, msg)
    # Union / discriminator tags never appear as if they were keys.
    for tag in ("literal[", "int.", "surface_collider.", "function-after"):
        assert tag not in msg, msg


def test_unknown_prior_is_named_with_the_closest_one(tmp_path):
    # Plug-in names are checked against the registries when a run config is loaded
    # (runconfig.check_plugins; config.py imports no plug-in package).
    from motionphysics.runconfig import load_run_config

    p = tmp_path / "cfg.yaml"
    p.write_text("optimize: {prior: cogvideo}\n")
    with pytest.raises(UserInputError) as err:
        load_run_config(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}: optimize.prior: got 'cogvideo'") and "\n" not in msg, msg
    assert "did you mean `cogvideox`?" in msg, msg


def test_several_errors_are_counted_in_the_one_line():
    with pytest.raises(UserInputError) as err:
        config_from_dict({"sim": {"grid": "x", "frames": "y"}, "camra": 1}, "c.yaml")
    msg = str(err.value)
    assert "(and 2 more problems)" in msg and "\n" not in msg


def test_parameter_of_another_class_names_the_file():
    with pytest.raises(UserInputError) as err:
        config_from_dict({"material": {"class": "elastic", "tau_Y": 100.0}}, "c.yaml")
    msg = str(err.value)
    assert msg.startswith("c.yaml: material: ") and "tau_Y" in msg and "E, nu" in msg


def test_yaml_file_errors_name_the_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("material: {E: -5.0}\n")
    with pytest.raises(UserInputError, match=r"bad\.yaml: material\.E: got -5\.0"):
        load_config(p)


@pytest.mark.parametrize("key", ["\r", "fr\name", " sim", ""])
def test_keys_with_control_characters_stay_on_one_line(key):
    with pytest.raises(UserInputError) as err:
        config_from_dict({key: 1}, "c.yaml")
    msg = str(err.value)
    assert msg.isprintable() and msg.startswith("c.yaml: ") and "unknown key" in msg


def test_an_unknown_key_of_any_length_stays_one_short_line():
    """Found by the property test: a 3-character key of astral-plane characters, escaped
    twice in the line, pushed the unknown-key line of optimize to 400 characters."""
    from motionphysics.config import config_from_dict
    from motionphysics.errors import UserInputError

    with pytest.raises(UserInputError) as e:
        config_from_dict({"optimize": {"\U00018cd6\U0002ebe1\U0002ebe1": 1}}, "cfg.yaml")
    msg = str(e.value)
    assert "unknown key" in msg and "\n" not in msg and len(msg) < 400, msg
