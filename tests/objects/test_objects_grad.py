"""One parameter vector per object: gradients of a trajectory loss with respect to each
object's own physical parameters, through contact, against central differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from motionphysics.assembly import assemble
from motionphysics.config import config_from_dict


def _assembly():
    def ball(name, x, v, E):
        return {
            "name": name,
            "source": "builtin:sphere",
            "scale": 0.12,
            "translate": [x, 0.0, 0.5],
            "max_particles": 40,
            "material": {"class": "elastic", "density": 500.0, "E": E, "nu": 0.3},
            "initial_velocity": [v, 0.0, 0.0],
        }

    cfg = config_from_dict(
        {
            "objects": [ball("a", -0.07, 2.0, 4.0e4), ball("b", 0.07, -2.0, 2.0e4)],
            "sim": {
                "domain": [[-0.3, -0.15, 0.35], [0.3, 0.15, 0.65]],
                "grid": 12,
                "frames": 3,
                "frame_dt": 0.01,
                "substeps": 10,
                "gravity": [0, 0, 0],
            },
        }
    )
    return assemble(cfg, needs_grad=True, estimate=False, reference_image=False)


def test_two_objects_parameters_have_their_own_gradients():
    asm = _assembly()
    sim = asm.simulator(per_object=True)
    oid = np.asarray(asm.sim_scene.object_id)
    P = sim.num_particles
    rng = np.random.default_rng(0)
    w = torch.tensor(rng.normal(size=(2, P, 3)))
    x0 = asm.sim_scene.particles.double()

    nu = torch.tensor(0.3, dtype=torch.float64)

    def loss(E_a, E_b, rho_b):
        phys = [{"density": 500.0, "E": E_a, "nu": nu}, {"density": rho_b, "E": E_b, "nu": nu}]
        xs, _ = sim.simulate(asm.to_sim_objects(phys), None, frames=(1, 2))
        return ((xs.double() - x0) * w).sum() * 10.0

    base = {"E_a": 4.0e4, "E_b": 2.0e4, "rho_b": 500.0}
    t = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in base.items()}
    loss(**t).backward()
    # the balls meet within the rollout (the contact slows them)
    with torch.no_grad():
        xs, _ = sim.simulate(
            asm.to_sim_objects(
                [{"density": 500.0, "E": 4e4, "nu": 0.3}, {"density": 500.0, "E": 2e4, "nu": 0.3}]
            ),
            None,
            frames=(2,),
        )
    drift = float((xs[0, oid == 0, 0].double() - x0[oid == 0, 0]).mean())
    assert drift < 0.9 * 2.0 * 0.02, drift
    for name, h in (("E_a", 400.0), ("E_b", 200.0), ("rho_b", 10.0)):
        vals = []
        for sgn in (1, -1):
            arg = {k: torch.tensor(v, dtype=torch.float64) for k, v in base.items()}
            arg[name] = arg[name] + sgn * h
            with torch.no_grad():
                vals.append(float(loss(**arg)))
        fd = (vals[0] - vals[1]) / (2 * h)
        got = float(t[name].grad)
        assert abs(fd) > 0
        assert got == pytest.approx(fd, rel=0.05, abs=1e-3 * abs(fd) + 1e-9), (name, got, fd)


def test_several_objects_need_the_per_object_simulator():
    # (refinement and fit build it through optimize.objects; the one-vector
    # simulator of one object cannot drive several)
    asm = _assembly()
    with pytest.raises(ValueError, match="per_object=True"):
        asm.simulator()
    assert asm.simulator(per_object=True).num_particles == asm.num_particles
