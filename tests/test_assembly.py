"""One simulation behind every command (issue 11): the assembly resolves ``substeps``
and the material map once, so ``simulate`` and the fit's differentiable forward at the
same parameters give the same trajectory, bit for bit; under ``auto`` the fit follows
the substep count the current parameters need."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from motionphysics.assembly import assemble
from motionphysics.config import config_from_dict
from motionphysics.losses.trajectory_match import TrajectoryMatchLoss
from motionphysics.materials.catalog import MaterialParams
from motionphysics.optimize.fit import build_problem

MATERIALS = {
    "elastic": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3},
    "plasticine": {"class": "plasticine", "density": 1500.0, "E": 2.0e6, "nu": 0.35, "tau_Y": 1e4},
    "newtonian": {"class": "newtonian", "density": 1000.0, "mu": 0.5, "kappa": 2.0e9},
}


def _cfg(material: dict, substeps):
    return config_from_dict(
        {
            "scene": {
                "source": "builtin:sphere",
                "scale": 0.3,
                "translate": [0, 0, 0.25],
                "max_particles": 150,
            },
            "material": material,
            "sim": {
                "grid": 10,
                "frames": 3,
                "frame_dt": 0.02,
                "substeps": substeps,
                "initial_velocity": [0.0, 0.0, -1.0],
            },
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
            "camera": {"width": 16, "height": 16},
        },
        "test",
    )


def _fit_forward(parts, theta=None):
    """The fit's forward (theta -> sim map -> bridge) over every frame, and its problem."""
    x0 = parts.sim_scene.particles.numpy()
    ref = np.repeat(x0[None], int(parts.cfg.sim.frames), axis=0)
    problem = build_problem(parts, TrajectoryMatchLoss(ref), list(parts.material.values))
    theta = theta or problem.initial_theta()
    frames = list(range(int(parts.cfg.sim.frames)))
    pred = problem.forward(theta, frames, "full", 8, {})
    return problem, theta, pred.xs.detach().numpy()


def _material_at(problem, material, theta) -> MaterialParams:
    with torch.no_grad():
        phys = problem.all_physical(theta)
    vals = {k: float(v) for k, v in phys.items()}
    return MaterialParams(material.cls, vals.pop("density"), vals)


# 20 fixed substeps: the smallest count here at which every class keeps its class
# (simmap.plan_substeps refuses plasticine at 12: it would flow under its own weight).
@pytest.mark.parametrize("substeps", [20, "auto"])
@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_simulate_and_fit_forward_are_bit_identical(name, substeps):
    cfg = _cfg(MATERIALS[name], substeps)
    fit_parts = assemble(cfg, needs_grad=True, estimate=False, reference_image=False)
    problem, theta, xs_fit = _fit_forward(fit_parts)
    # ``simulate`` at the parameters theta stands for (float32 from the theta map; the
    # fixed ones exactly as the config gives them)
    material = _material_at(problem, fit_parts.material, theta)
    fwd = assemble(cfg, estimate=False, reference_image=False).with_material(material)
    xs_sim, _, _, n_sim = fwd.simulate()
    assert problem.simulator.substeps == n_sim
    if substeps != "auto":
        assert n_sim == substeps
    assert xs_fit.shape == xs_sim.shape
    assert np.array_equal(xs_fit, xs_sim), float(np.abs(xs_fit - xs_sim).max())


def test_fit_re_resolves_auto_substeps_when_the_parameters_move():
    cfg = _cfg(MATERIALS["elastic"], "auto")
    parts = assemble(cfg, needs_grad=True, estimate=False, reference_image=False)
    problem, theta, _ = _fit_forward(parts)
    n0 = problem.simulator.substeps
    with torch.no_grad():
        stiff = {k: v.clone() for k, v in theta.items()}
        # a hundred times stiffer: the P-wave speed (and so the CFL substep count) rises
        target = problem.theta_map.to_theta({"E": 2.0e9, "nu": 0.3}).float()
        stiff["E"] = target[0].clone().requires_grad_(True)
    pred = problem.forward(stiff, list(range(int(cfg.sim.frames))), "full", 8, {})
    xs_fit = pred.xs.detach().numpy()
    n1 = problem.simulator.substeps
    assert n1 > n0 and problem.simulator.changes[-1] == (n0, n1)
    material = _material_at(problem, parts.material, stiff)
    xs_sim, _, _, n_sim = (
        assemble(cfg, estimate=False, reference_image=False).with_material(material).simulate()
    )
    assert n_sim == n1 and np.array_equal(xs_fit, xs_sim)


def test_simulate_command_and_fit_forward_agree(tmp_path):
    """The same through the command line: ``simulate``'s trajectory.npz is the fit's forward."""
    import yaml

    from motionphysics.cli import main

    data = {
        "scene": {
            "source": "builtin:sphere",
            "scale": 0.3,
            "translate": [0, 0, 0.25],
            "max_particles": 150,
        },
        "material": {"class": "elastic", "density": 1000.0, "E": 2.5e7, "nu": 0.25},
        "sim": {"grid": 10, "frames": 3, "frame_dt": 0.02, "substeps": "auto"},
        "boundary_conditions": [{"type": "bounding_box"}],
        "camera": {"width": 16, "height": 16},
    }
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["--quiet", "simulate", str(path), "--out", str(tmp_path / "s")]) == 0
    with np.load(tmp_path / "s" / "trajectory.npz") as z:
        xs_cmd = z["x"]
    params = json.loads((tmp_path / "s" / "params.json").read_text())
    cfg = config_from_dict(data, "test")
    parts = assemble(cfg, needs_grad=True, estimate=False, reference_image=False)
    problem, _, xs_fit = _fit_forward(parts)
    # E = 2.5e7 and nu = 0.25 survive the float32 theta round trip only approximately;
    # forward at the config's own values instead (theta of exactly those floats).
    from motionphysics.assembly import resolve_simulation

    assert (
        params["sim_context"]["substeps"]
        == resolve_simulation(parts.material, parts.cfg, parts.sim_scene).substeps
    )
    sim = parts.simulator()
    vals = {k: torch.tensor(v, dtype=torch.float64) for k, v in parts.resolution.values.items()}
    xs, _ = sim.simulate(vals, None, [0, 1, 2], "full", 8)
    assert np.array_equal(xs.detach().numpy(), xs_cmd)


def test_resolution_is_the_one_record_of_the_simulation(tiny_assembly):
    res = tiny_assembly.resolution
    rec = res.record()
    assert rec["substeps"] == 12 and rec["substeps_mode"] == "fixed"
    assert rec["dt"] == pytest.approx(0.02 / 12) and rec["dt_map"] == pytest.approx(0.02 / 12)
    # the differentiable map and the forward commands' values are the same numbers
    phys = {"density": 1000.0, "E": 2.0e7, "nu": 0.3}
    sim = tiny_assembly.to_sim(phys)
    assert all(sim[k].dtype == torch.float64 for k in sim)
    assert {k: float(v) for k, v in sim.items()} == res.values
    # another material: resolved again by the same functions, the scene kept
    soft = MaterialParams("elastic", 1000.0, {"E": 1.0e7, "nu": 0.3})
    other = tiny_assembly.with_material(soft)
    assert (
        other.sim_scene is tiny_assembly.sim_scene
        and other.resolution.values["E"] < res.values["E"]
    )
