"""A body that slumps under its own weight at the size it is simulated is told so, through
``motionphysics simulate CONFIG``: "A jelly cube wobbles" on the 1 m ``builtin:cube``
(kb jelly, E 5 kPa) sank to half its height and read as neither a wobble nor a bounce,
without a word on why (density x g x height / E = 2.1: the physics of a metre of jelly).
The same cube at 10 cm (0.21) wobbles, and nothing is said."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from motionphysics.cli import main

JELLY = {"class": "elastic", "density": 1050.0, "E": 5000.0, "nu": 0.45}


@pytest.mark.parametrize("scale, slumps", [(1.0, True), (0.1, False)])
def test_a_jelly_cube_is_told_when_its_size_makes_it_slump(tmp_path, capsys, scale, slumps):
    data = {
        "prompt": "A jelly cube wobbles.",
        "scene": {"source": "builtin:cube", "scale": scale, "max_particles": 800},
        "material": JELLY,
        "sim": {"grid": 16, "frames": 8, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }
    path = tmp_path / "jelly.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    capsys.readouterr()
    assert main(["simulate", str(path), "--out", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    lines = [s for s in err.splitlines() if "its own weight strains" in s]
    assert bool(lines) == slumps, err
    if slumps:
        (line,) = lines
        strain = (
            1050
            * 9.8
            * float(np.ptp(np.load(tmp_path / "run" / "trajectory.npz")["x"][0, :, 2]))
            / 5000
        )
        assert f"by {100 * strain:.0f} %" in line
        assert "`scene.scale`" in line and "builtins are 1 m unless scaled" in line
