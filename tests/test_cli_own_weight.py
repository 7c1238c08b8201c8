"""A body that slumps under its own weight at the size it is simulated is told so, through
``motionphysics simulate CONFIG``: "A jelly cube wobbles" on the 1 m ``builtin:cube``
(kb jelly, E 5 kPa) sank to half its height and read as neither a wobble nor a bounce,
without a word on why (density x g x height / E = 2.1: the physics of a metre of jelly).
The same cube at 10 cm (0.21) wobbles, and nothing is said. Likewise a metre of honey
asked to ooze runs out like water (its viscous time is 2 ms): the run names the
viscosity that oozes over the clip."""

from __future__ import annotations

import re

import numpy as np
import pytest

JELLY = {"class": "elastic", "density": 1050.0, "E": 5000.0, "nu": 0.45}


@pytest.mark.parametrize("scale, slumps", [(1.0, True), (0.1, False)])
def test_a_jelly_cube_is_told_when_its_size_makes_it_slump(cli_run, scale, slumps):
    data = {
        "prompt": "A jelly cube wobbles.",
        "scene": {"source": "builtin:cube", "scale": scale, "max_particles": 800},
        "material": JELLY,
        "sim": {"grid": 16, "frames": 8, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }
    run = cli_run(data, "jelly")
    assert run.rc == 0
    lines = [s for s in run.err.splitlines() if "its own weight strains" in s]
    assert bool(lines) == slumps, run.err
    if slumps:
        (line,) = lines
        height = float(np.ptp(run.trajectory()["x"][0, :, 2]))
        assert f"by {100 * 1050 * 9.8 * height / 5000:.0f} %" in line
        assert "`scene.scale`" in line and "builtins are 1 m unless scaled" in line


def _run_honey(cli_run, name: str, mu: float):
    data = {
        "prompt": "A block of thick honey oozes slowly.",
        "scene": {"source": "builtin:cube", "scale": 1.0, "max_particles": 800},
        "material": {"class": "newtonian", "density": 1420.0, "mu": mu, "kappa": 2.5e9},
        "sim": {"grid": 16, "frames": 20, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }
    run = cli_run(data, name, "run")
    assert run.rc == 0
    return [s for s in run.err.splitlines() if "viscous time" in s], run.params


def test_a_metre_of_honey_asked_to_ooze_is_told_the_viscosity_an_ooze_needs(cli_run):
    # honey (30 Pa s) at 1 m: viscous time mu / (rho g h) = 2 ms against a 0.76 s clip, so
    # it runs out like water; the line names the mu that oozes over the clip, and that mu
    # does ooze (and says nothing)
    lines, params = _run_honey(cli_run, "honey", 30.0)
    assert len(lines) == 1 and "runs out within the first frames rather than oozing" in lines[0]
    assert params["metrics"]["motion"]["simulated"]["group"] != "oozes"
    need = float(re.search(r"needs mu of about ([0-9.e+]+) Pa s", lines[0]).group(1))
    assert 200 < need < 1000  # 0.05 x 1420 x 9.8 x ~0.9 m x 0.76 s
    lines, params = _run_honey(cli_run, "thick", need)
    assert lines == [] and params["metrics"]["motion"]["simulated"]["group"] == "oozes"
