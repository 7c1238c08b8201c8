"""A liquid, a paste or sand that spreads has room to, through ``motionphysics simulate
CONFIG``: a fitted domain is widened across gravity at the same cell size once the
material class is known. A water ball dropped on the default ground hit an invisible wall
at half its run-out and sloshed back (the summary warned "material reached the domain wall
x-", eval's adherence to "splashes" read 0.09); it now spreads out on the floor.

Judged on params.json (dx, grid_dims, the `domain` note), the summary, stderr and the
trajectory.
"""

from __future__ import annotations

import numpy as np
import pytest

WATER = {"class": "newtonian", "density": 1000.0, "mu": 0.001, "kappa": 2.0e6}
RUBBER = {"class": "elastic", "density": 1000.0, "E": 3.0e5, "nu": 0.3}
SAND = {"class": "sand", "density": 1600.0, "theta_fric": 33.0}


def _simulate(cli_run, data: dict, name: str):
    run = cli_run(data, name)
    assert run.rc == 0
    return run.params, run.trajectory(), run.out, run.err


def _drop(material: dict, frames: int = 2, **sim) -> dict:
    return {
        "prompt": "A ball of it is dropped onto the ground and spreads.",
        "scene": {"source": "builtin:sphere", "scale": 0.2, "max_particles": 1500},
        "material": material,
        "sim": {"grid": 20, "frames": frames, "frame_dt": 0.04, "substeps": "auto", **sim},
        "camera": {"width": 24, "height": 24},
    }


@pytest.mark.parametrize("material, spread", [(WATER, 3.0), (SAND, 2.0)])
def test_a_material_that_spreads_gets_room_at_the_same_cell_size(cli_run, material, spread):
    solid, *_ = _simulate(cli_run, _drop(RUBBER), "solid")
    params, traj, out, _ = _simulate(cli_run, _drop(material), "spreads")
    a, b = solid["scene"], params["scene"]
    assert b["dx"] == pytest.approx(a["dx"], rel=1e-12)  # the same cells ...
    assert b["grid_dims"][2] == a["grid_dims"][2]  # ... along gravity: as fitted
    added = (b["grid_dims"][0] - a["grid_dims"][0]) // 2
    assert added > 0 and b["grid_dims"][1] == b["grid_dims"][0]
    # the walls now stand `spread` object heights (0.2 m) or more from the ball's side
    x0 = traj["x"][0]
    room = min(x0[:, 0].min() - b["domain_lo"][0], b["domain_hi"][0] - x0[:, 0].max())
    assert room >= spread * 0.2 * 0.9
    line = next(s for s in out.splitlines() if s.startswith("domain:"))
    assert f"{added} cells" in line and f"room for the {material['class']} to spread" in line
    assert b["domain"] == line.replace("domain:   ", "domain:", 1)
    # particles keep their place relative to the nodes: whole cells were added
    shift = (np.asarray(a["domain_lo"]) - np.asarray(b["domain_lo"])) / b["dx"]
    assert np.allclose(shift, np.round(shift), atol=1e-4)


def test_a_water_ball_splashes_out_without_meeting_a_wall(cli_run):
    data = _drop(WATER, frames=16)
    params, traj, out, err = _simulate(cli_run, data, "splash")
    assert "reached the domain wall" not in err
    x = traj["x"].astype(np.float64)
    width0 = np.ptp(x[0, :, 0])
    assert np.ptp(x[-1, :, 0]) > 2.5 * width0  # it ran out across the floor
    # and the sheet did not pile up against anything: no particle at a wall
    lo, hi = np.asarray(params["scene"]["domain_lo"]), np.asarray(params["scene"]["domain_hi"])
    dx = params["scene"]["dx"]
    assert (x[:, :, :2] > lo[:2] + 4 * dx).all() and (x[:, :, :2] < hi[:2] - 4 * dx).all()


def test_a_given_domain_and_a_solid_are_left_as_they_are(cli_run):
    given = _drop(WATER, domain=[[-0.5, -0.5, -0.3], [0.5, 0.5, 0.4]])
    params, _, out, _ = _simulate(cli_run, given, "given")
    assert "domain" not in params["scene"] and not any(
        s.startswith("domain:") for s in out.splitlines()
    )
    params, _, out, _ = _simulate(cli_run, _drop(RUBBER), "rubber")
    assert "domain" not in params["scene"]
