"""A loss on rendered pixels back-propagates through the renderer and the Warp tape
into a material parameter (checkpointed gradient vs central finite differences)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motionphysics.sim.bridge import simulate
from motionphysics.sim.build import Simulation
from motionphysics.sim.model import Model
from motionphysics.sim.solver import Solver

render = pytest.importorskip("motionphysics.render.deform", reason="renderer module not available")

DX = 1.0 / 16


def _setup():
    from motionphysics.render.camera import orbit_camera
    from motionphysics.scene.gaussians import GaussianScene

    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    x = 0.5 + (g - g.mean(axis=0)) * (DX / 2)
    P = x.shape[0]
    rng = np.random.default_rng(3)
    splats = GaussianScene(
        means=torch.tensor(x, dtype=torch.float32),
        log_scales=torch.full((P, 3), float(np.log(DX / 3))),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(P, 1),
        logit_opacities=torch.full((P,), 2.0),
        sh=torch.tensor(rng.uniform(-1.0, 1.0, (P, 1, 3)), dtype=torch.float32),
    )
    scene = SimpleNamespace(
        splats=splats, splat_parent=torch.arange(P), splat_offset=torch.zeros(P, 3)
    )
    model = Model.from_particles(
        np.full(P, (DX / 2) ** 3),
        {"class": "elastic", "density": 100.0, "E": 4.0e4, "nu": 0.3},
        (0, 0, 0),
        DX,
        (17, 17, 17),
        gravity=(0.0, 0.0, 0.0),
        requires_grad=True,
    )
    sim = Simulation(model, Solver(model), model.state(x, requires_grad=True), 12, 4.0e-3, frames=3)
    r = x - x.mean(axis=0)
    v0 = torch.tensor(
        np.stack([-8.0 * r[:, 0] + 3.0 * r[:, 2], 6.0 * r[:, 1], 5.0 * r[:, 0]], -1),
        dtype=torch.float32,
    )
    cam = orbit_camera(30.0, 20.0, 0.6, look_at=(0.5, 0.5, 0.5), fov=40.0, width=24, height=24)
    target = torch.tensor(rng.uniform(0.0, 1.0, (1, 24, 24, 3)), dtype=torch.float32)
    return scene, sim, v0, cam, target


def test_pixel_loss_gradient_to_youngs_modulus():
    scene, sim, v0, cam, target = _setup()

    def loss(E):
        xs, Fs = simulate(sim, {"E": E}, frames=[2], initial_velocity=v0)
        rgb = render.render_frames(scene, xs, Fs, cam, background=(1.0, 1.0, 1.0))
        return ((rgb.double() - target.double()) ** 2).sum()

    E = torch.tensor(4.0e4, requires_grad=True)
    loss(E).backward()
    h = 3e-2 * 4.0e4
    with torch.no_grad():
        fd = (float(loss(torch.tensor(4.0e4 + h))) - float(loss(torch.tensor(4.0e4 - h)))) / (2 * h)
    assert abs(fd) * 4.0e4 > 1e-3, "pixels insensitive to E: the test would be vacuous"
    # float32 simulation + float32 rasteriser; 3 % FD step as in test_gradients.py; 5 % tolerance
    assert float(E.grad) == pytest.approx(fd, rel=5e-2)
