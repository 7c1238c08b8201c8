"""Solver / builder / rollout behaviour: build_simulation from a RunConfig, auto
substeps, divergence errors, particles kept inside the grid, boundary hooks, mixed
materials, the bridge's frame selection, force-magnitude gradients, and CUDA parity."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motionphysics.config import RunConfig, config_from_dict
from motionphysics.errors import SimulationError, UserInputError
from motionphysics.sim.bridge import simulate
from motionphysics.sim.build import build_simulation
from motionphysics.sim.model import Model
from motionphysics.sim.solver import auto_substeps, cfl_number, stable_dt

DX = 1.0 / 16


def _scene(n_side=5, centre=(0.5, 0.5, 0.3), spacing=DX / 2, dims=(17, 17, 17)):
    """A SimScene stand-in (the fields build_simulation reads): a cube of particles."""
    g = np.stack(np.meshgrid(*[np.arange(n_side)] * 3, indexing="ij"), -1).reshape(-1, 3)
    x = np.asarray(centre) + (g - g.mean(axis=0)) * spacing
    return SimpleNamespace(
        particles=torch.tensor(x, dtype=torch.float32),
        volumes=torch.full((x.shape[0],), spacing**3),
        domain_lo=torch.zeros(3),
        dx=DX,
        grid_dims=dims,
    )


def _cfg(**sim) -> RunConfig:
    base = {"grid": 16, "frames": 4, "frame_dt": 0.02, "substeps": "auto"}
    return config_from_dict({"sim": {**base, **sim}})


ELASTIC = {"class": "elastic", "density": 200.0, "E": 2.0e4, "nu": 0.3}


def test_build_and_run_keeps_particles_inside_grid():
    scene = _scene(centre=(0.5, 0.5, 0.25))
    sim = build_simulation(scene, _cfg(initial_velocity=(3.0, 0.0, -4.0), frames=6), ELASTIC)
    xs, Fs, vs = sim.run(return_velocities=True)
    P = scene.particles.shape[0]
    assert xs.shape == (6, P, 3) and Fs.shape == (6, P, 3, 3) and vs.shape == (6, P, 3)
    np.testing.assert_allclose(xs[0], scene.particles.numpy())
    np.testing.assert_allclose(Fs[0], np.broadcast_to(np.eye(3), (P, 3, 3)))
    np.testing.assert_allclose(vs[0], np.broadcast_to([3.0, 0.0, -4.0], (P, 3)))
    # The block flies into the -z and +x walls within 0.1 s; without boundary conditions the
    # solver still keeps every particle >= 2 cells inside the grid.
    lo, hi = 2 * DX, (17 - 3) * DX
    assert xs.min() >= lo - 1e-6 and xs.max() <= hi + 1e-6
    assert xs[-1, :, 2].min() == pytest.approx(lo, abs=1e-6)
    assert np.isfinite(Fs).all()


def test_auto_substeps_from_cfl_and_viscosity():
    E, nu, rho = 2.0e4, 0.3, 200.0
    c = math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)) / rho)
    assert stable_dt(ELASTIC, DX) == pytest.approx(0.4 * DX / c, rel=1e-6)
    assert auto_substeps(ELASTIC, DX, 0.02) == math.ceil(0.02 / (0.4 * DX / c))
    # viscosity-limited Newtonian fluid: dt <= 0.5 rho dx^2 / (6 mu)
    fluid = {"class": "newtonian", "density": 1000.0, "mu": 50.0, "kappa": 1.0e3}
    dt_visc = 0.5 * 1000.0 * DX**2 / (6 * 50.0)
    assert stable_dt(fluid, DX) == pytest.approx(dt_visc, rel=1e-6)
    # per-particle values: the stiffest particle decides
    mixed = {
        "class": np.array([0, 0, 2]),
        "density": 200.0,
        "E": np.array([1e3, 2e4, 8e4]),
        "nu": 0.3,
        "tau_Y": 10.0,
    }
    assert stable_dt(mixed, DX) == pytest.approx(stable_dt({**ELASTIC, "E": 8e4}, DX), rel=1e-6)
    sim = build_simulation(_scene(), _cfg(), ELASTIC)
    assert sim.substeps == auto_substeps(ELASTIC, DX, 0.02)
    assert cfl_number(sim.model, DX, sim.dt) <= 0.4 + 1e-9


def test_divergence_raises_simulation_error_with_frame_and_cfl():
    stiff = {**ELASTIC, "E": 5.0e7}
    sim = build_simulation(_scene(), _cfg(substeps=2, initial_velocity=(0.0, 0.0, -1.0)), stiff)
    with pytest.raises(SimulationError, match=r"frame \d+ .*CFL number[^=]*= [0-9.]+"):
        sim.run()


@pytest.mark.parametrize(
    ("material", "field"),
    [
        ({"class": "elastic", "density": 1.0, "nu": 0.3}, "material.E"),
        ({"class": "glass", "density": 1.0, "E": 1.0, "nu": 0.3}, "material.class"),
        ({"class": "elastic", "density": 1.0, "E": 1.0, "nu": 0.5}, "material.nu"),
        ({"class": "elastic", "density": 1.0, "E": np.ones(3), "nu": 0.3}, "material.E"),
        (
            {"class": "sand", "density": 1.0, "E": 1.0, "nu": 0.3, "theta_fric": 95.0},
            "material.theta_fric",
        ),
        ({"class": "elastic", "density": -1.0, "E": 1.0, "nu": 0.3}, "material.density"),
        ({"class": "elastic", "density": 1.0, "E": 1.0, "nu": 0.3, "zeta": 1.0}, "material"),
    ],
)
def test_bad_material_is_user_input_error(material, field):
    with pytest.raises(UserInputError, match=field.replace(".", r"\.")) as err:
        Model.from_particles(np.ones(5), material, (0, 0, 0), DX, (17, 17, 17))
    assert "\n" not in str(err.value)


def test_mixed_materials_in_one_scene():
    """A metal half and a Newtonian-fluid half on a floor: the fluid column collapses, the
    metal column keeps its height."""
    scene = _scene(n_side=6, centre=(0.5, 0.5, 0.3))
    x = scene.particles.numpy()
    fluid = x[:, 0] > 0.5
    mat = {
        "class": np.where(fluid, 5, 2),
        "density": 500.0,
        "E": 5.0e4,
        "nu": 0.3,
        "tau_Y": 2e3,
        "mu": 0.1,
        "kappa": 5.0e4,
    }
    cfg = config_from_dict(
        {
            "sim": {"grid": 16, "frames": 12, "frame_dt": 0.02, "substeps": "auto"},
            "boundary_conditions": [
                {
                    "type": "surface_collider",
                    "point": [0, 0, 0.2],
                    "normal": [0, 0, 1],
                    "mode": "slip",
                }
            ],
        }
    )
    sim = build_simulation(scene, cfg, mat)
    xs, Fs = sim.run()
    top0 = x[:, 2].max()
    drop_fluid = top0 - xs[-1, fluid, 2].max()
    drop_metal = top0 - xs[-1, ~fluid, 2].max()
    assert drop_fluid > 0.04 and drop_metal < 0.015, (drop_fluid, drop_metal)
    # the fluid keeps F = J^(1/3) I
    Ff = Fs[-1, fluid]
    np.testing.assert_allclose(Ff - np.eye(3) * Ff[:, :1, :1], 0.0, atol=1e-5)


def test_ball_bounces_on_surface_collider():
    scene = _scene(n_side=5, centre=(0.5, 0.5, 0.35))
    cfg = config_from_dict(
        {
            "sim": {
                "grid": 16,
                "frames": 16,
                "frame_dt": 0.02,
                "substeps": "auto",
                "initial_velocity": [0, 0, -2.0],
            },
            "boundary_conditions": [
                {
                    "type": "surface_collider",
                    "point": [0, 0, 0.2],
                    "normal": [0, 0, 1],
                    "mode": "slip",
                }
            ],
        }
    )
    sim = build_simulation(scene, cfg, {**ELASTIC, "E": 1.0e5})
    xs, _, vs = sim.run(return_velocities=True)
    zmin = xs[:, :, 2].min(axis=1)
    assert zmin.min() > 0.2 - DX  # the plane holds (within the B-spline half-width)
    vz = vs[:, :, 2].mean(axis=1)
    assert vz[0] < -1.5 and vz.max() > 0.3, vz  # falls, then moves up again


def test_bridge_returns_requested_frames():
    sim = build_simulation(
        _scene(), _cfg(frames=5, initial_velocity=(0, 1.0, 0)), ELASTIC, requires_grad=True
    )
    xs_all, Fs_all = sim.run()
    xs, Fs = simulate(sim, frames=[4, 1, 2])
    assert xs.shape == (3, sim.model.particle_count, 3) and Fs.shape[1:] == (
        sim.model.particle_count,
        3,
        3,
    )
    np.testing.assert_allclose(xs.numpy(), xs_all[[4, 1, 2]])
    np.testing.assert_allclose(Fs.numpy(), Fs_all[[4, 1, 2]])
    with pytest.raises(ValueError):
        simulate(sim, frames=[])


def test_force_magnitude_gradient_matches_finite_differences():
    scene = _scene(n_side=4)
    cfg = config_from_dict(
        {
            "sim": {
                "grid": 16,
                "frames": 3,
                "frame_dt": 0.01,
                "substeps": 10,
                "gravity": [0, 0, 0],
            },
            "forces": [
                {
                    "type": "add_constant_force",
                    "force": [1.0, 0.0, 2.0],
                    "box": [[0.4, 0.4, 0.2], [0.52, 0.6, 0.4]],
                }
            ],
        }
    )
    sim = build_simulation(scene, cfg, ELASTIC, requires_grad=True)
    name = sim.model.boundary.params[0].name
    rng = np.random.default_rng(0)
    w = torch.tensor(rng.normal(size=(1, scene.particles.shape[0], 3)))

    def loss(f):
        xs, _ = simulate(sim, forces={name: f}, frames=[2])
        return ((xs.double() - scene.particles.double()) * w).sum() * 100.0

    f = torch.tensor([1.0, 0.0, 2.0], requires_grad=True)
    loss(f).backward()
    for a in range(3):
        e = torch.zeros(3)
        e[a] = 0.5
        with torch.no_grad():
            fd = (float(loss(f.detach() + e)) - float(loss(f.detach() - e))) / 1.0
        # the displacement is nearly linear in the force (small elastic response), so a large
        # FD step (0.5 m/s^2) has negligible truncation; smaller steps move the particles by
        # ~1e-5 m, where float32 round-off of x ~ 0.5 m dominates. 3 % tolerance.
        assert float(f.grad[a]) == pytest.approx(fd, rel=3e-2, abs=1e-4), a


@pytest.mark.cuda
@pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA device (torch.cuda.is_available() is False)"
)
def test_cuda_matches_cpu():
    scene = _scene()
    cfg = _cfg(frames=4, initial_velocity=(0.5, 0.0, -1.0))
    xs_c, Fs_c = build_simulation(scene, cfg, ELASTIC, device="cpu").run()
    xs_g, Fs_g = build_simulation(scene, cfg, ELASTIC, device="cuda").run()
    # atomics sum in a different order on the GPU: float32 round-off only
    np.testing.assert_allclose(xs_g, xs_c, atol=1e-5)
    np.testing.assert_allclose(Fs_g, Fs_c, atol=1e-4)


def test_bridge_backward_after_an_interleaved_run():
    """A forward-only run between simulate() and backward() must not corrupt the gradient."""
    sim = build_simulation(
        _scene(n_side=3), _cfg(frames=3, initial_velocity=(0, 0, -2.0)), ELASTIC, requires_grad=True
    )
    E = torch.tensor(2.0e4, requires_grad=True)
    xs, _ = simulate(sim, {"E": E}, frames=[2])
    (xs[..., 2] * torch.linspace(0, 1, xs.shape[1])).sum().backward()
    g_ref = float(E.grad)
    E.grad = None
    xs, _ = simulate(sim, {"E": E}, frames=[2])
    sim.run()  # replaces the rollout's checkpoints
    (xs[..., 2] * torch.linspace(0, 1, xs.shape[1])).sum().backward()
    assert g_ref != 0.0
    assert float(E.grad) == pytest.approx(g_ref, rel=1e-5)


def test_record_tapes_keeps_trailing_frames_with_identical_gradients(monkeypatch):
    """``Rollout.forward(record_tapes=True)`` records the trailing frames whose tapes fit
    ``tape_memory`` as it simulates them, and the full backward starts from those tapes:
    same positions and bit-identical gradients (a recorded step runs the same kernels on
    the same inputs) whether all, some or none of the frames are kept; only the frames not
    kept are recomputed. A window backward or a later forward drops the kept tapes."""
    from motionphysics.sim.rollout import Rollout

    cfg = _cfg(frames=5, initial_velocity=(0, 0, -2.0))
    sim = build_simulation(_scene(n_side=4), cfg, ELASTIC, requires_grad=True)
    ro = sim.rollout
    rng = np.random.default_rng(3)
    p = sim.model.particle_count
    adj = {f: {"x": rng.normal(size=(p, 3)), "F": rng.normal(size=(p, 3, 3))} for f in (2, 4)}
    records = []
    real = Rollout._record
    monkeypatch.setattr(
        Rollout, "_record", lambda self, k0, k1, *a: records.append(k0) or real(self, k0, k1, *a)
    )
    S = ro.substeps

    def grads(record_tapes, budget):
        ro.tape_memory = budget
        res = ro.forward(sim.state0, 5, record_tapes=record_tapes)
        kept = ro.kept_frames
        records.clear()  # count what the backward records
        sim.model.zero_grad()
        adj0 = ro.backward(adj, grad_mode="full")
        g = {k: a.grad.numpy().copy() for k, a in sim.model.params.items()}
        return res.xs, adj0.x.numpy().copy(), adj0.v.numpy().copy(), g, kept, list(records)

    xs0, ax0, av0, g0, kept0, rec0 = grads(False, 1 << 34)
    assert kept0 == [] and rec0 == [3 * S, 2 * S, S, 0]  # every frame recomputed
    assert np.any(g0["E"] != 0)
    per_frame = ro._span_bytes(S, 0)  # the estimate forward uses (needs its checkpoints)
    # all four frames fit; two fit (the trailing two); none fit (a tape of one frame
    # exceeds the budget: the backward also goes step-wise)
    for budget, kept, rec in (
        (1 << 34, [1, 2, 3, 4], []),
        (int(2.2 * per_frame), [3, 4], [S, 0]),
        (per_frame // 2, [], []),
    ):
        xs1, ax1, av1, g1, kept1, rec1 = grads(True, budget)
        assert kept1 == kept, budget
        if budget >= per_frame:
            assert rec1 == rec
        np.testing.assert_array_equal(xs1, xs0)
        np.testing.assert_array_equal(ax1, ax0)
        np.testing.assert_array_equal(av1, av0)
        for k in g0:
            np.testing.assert_array_equal(g1[k], g0[k], err_msg=k)
    # a window backward ignores (and drops) the kept tapes; so does a later forward
    ro.tape_memory = 1 << 34
    ro.forward(sim.state0, 5, record_tapes=True)
    assert ro.kept_frames == [1, 2, 3, 4]
    ro.backward(adj, grad_mode="window", window=2)
    assert ro.kept_frames == []
    ro.forward(sim.state0, 5, record_tapes=True)
    ro.forward(sim.state0, 5)
    assert ro.kept_frames == []


def _hooked_sim(n_side=4):
    """A block under every kind of recorded hook (grid and particle, forces and cuts)."""
    ground = {"type": "surface_collider", "mode": "frictional", "friction": 0.4}
    bcs = [
        ground,
        {"type": "bounding_box", "friction": 0.2},
        {"type": "clamp_grid", "box": [[0.0, 0.0, 0.0], [0.2, 1.0, 1.0]]},
        {"type": "surface_collider", "mode": "cut", "point": [0.62, 0, 0], "normal": [-1, 0, 0]},
    ]
    box = [[0.0, 0.0, 0.0], [0.5, 1.0, 1.0]]
    forces = [
        {"type": "add_constant_force", "force": [3.0, 1.0, -2.0], "box": box},
        {"type": "add_impulse", "force": [0.0, 2.0, 0.0], "start": 0.0, "end": 0.03},
        {"type": "force_particles_translation", "velocity": [0.0, 0.0, -0.5], "box": box,
         "start": 0.0, "end": 0.01},
        {"type": "force_particles_rotation", "center": [0.5, 0.5, 0.3],
         "angular_velocity": 3.0, "box": [[0.5, 0.0, 0.0], [1.0, 1.0, 1.0]], "end": 0.02},
        {"type": "release_particles", "layers": 2, "start": 0.0, "end": 0.04,
         "box": [[0.0, 0.0, 0.32], [1.0, 1.0, 1.0]]},
    ]  # fmt: skip
    cfg = config_from_dict(
        {
            "sim": {"grid": 16, "frames": 4, "frame_dt": 0.02, "substeps": "auto",
                    "initial_velocity": [1.0, 0.0, -2.0]},
            "boundary_conditions": bcs,
            "forces": forces,
        }
    )  # fmt: skip
    return build_simulation(_scene(n_side=n_side), cfg, ELASTIC, requires_grad=True)


def test_a_complete_backward_leaves_the_reused_tape_buffers_clean():
    """The rollout zeroes only the tape buffers a backward may have left non-zero: a
    complete full backward consumes every adjoint it reads but the first state's (the
    adjoint kernels zero their output adjoints). Checked with every kind of hook
    recording; a second forward + backward on the reused buffers then gives exactly the
    gradients of a rollout with fresh buffers."""
    from motionphysics.sim.rollout import Rollout
    from motionphysics.sim.state import State

    sim = _hooked_sim()
    ro = sim.rollout
    p = sim.model.particle_count
    rng = np.random.default_rng(5)

    def adjoints():
        return {f: {"x": rng.normal(size=(p, 3)), "F": rng.normal(size=(p, 3, 3))} for f in (1, 3)}

    def grads(sim, rollout, adj):
        rollout.forward(sim.state0, 4, record_tapes=True, check=False)
        sim.model.zero_grad()
        sim.model.boundary.zero_param_grads()
        a0 = rollout.backward(adj, grad_mode="full")
        g = {k: a.grad.numpy().copy() for k, a in sim.model.params.items()}
        return g, sim.model.boundary.param_grads(), a0.x.numpy().copy()

    ro.tape_memory = 1 << 34
    first = grads(sim, ro, adjoints())
    assert np.any(first[0]["E"] != 0) and np.any(first[2] != 0)
    slots = sim.solver._rollout_buffers["slots"]
    assert len(slots) == 3  # frames 1-3 kept
    for bufs in slots:
        n = ro.substeps
        for s in bufs["tstates"][1 : n + 1]:
            for f in State.FIELDS:
                assert not np.any(getattr(s, f).grad.numpy()), f
        for g in bufs["tgrids"][:n]:
            # (the node velocity adjoint is zeroed on its region by each recorded step)
            assert not np.any(g.affine.grad.numpy())
    adj = adjoints()
    again = grads(sim, ro, adj)
    fresh_sim = _hooked_sim()
    fresh_ro = Rollout(fresh_sim.solver, ro.substeps, ro.frame_dt, tape_memory=1 << 34)
    fresh = grads(fresh_sim, fresh_ro, adj)
    for k in again[0]:
        np.testing.assert_array_equal(again[0][k], fresh[0][k], err_msg=k)
    for k in again[1]:
        np.testing.assert_array_equal(again[1][k], fresh[1][k], err_msg=k)
    np.testing.assert_array_equal(again[2], fresh[2])


def test_a_new_rollout_of_the_solver_reuses_its_buffers_and_drops_the_old_ones_tapes():
    """Tape buffers belong to the solver: a rollout made again (a new substep count) takes
    them over, and the rollout that recorded into them before drops its kept tapes (its
    full backward recomputes those frames: same gradients)."""
    from motionphysics.sim.rollout import Rollout

    cfg = _cfg(frames=3, initial_velocity=(0, 0, -2.0))
    sim = build_simulation(_scene(n_side=3), cfg, ELASTIC, requires_grad=True)
    p = sim.model.particle_count
    adj = {2: {"x": np.random.default_rng(1).normal(size=(p, 3))}}
    a = sim.rollout
    a.forward(sim.state0, 3, record_tapes=True)
    sim.model.zero_grad()
    a.backward(adj)
    ref = sim.model.params["E"].grad.numpy().copy()
    bufs = sim.solver._rollout_buffers
    a.forward(sim.state0, 3, record_tapes=True)
    assert a.kept_frames == [1, 2]
    b = Rollout(sim.solver, a.substeps + 1, a.frame_dt)
    b.forward(sim.state0, 3, record_tapes=True)
    assert sim.solver._rollout_buffers is bufs and b.kept_frames == [1, 2]
    assert a.kept_frames == []
    sim.model.zero_grad()
    a.backward(adj)  # a's checkpoints are its own: recomputed, same gradient
    np.testing.assert_array_equal(sim.model.params["E"].grad.numpy(), ref)
