"""Gradients through many substeps: tape (checkpointed, via the torch bridge) vs central
finite differences, for every parameter of every material class, density and initial
velocity; truncated modes; per-particle parameters."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from motionphysics.sim.bridge import simulate
from motionphysics.sim.build import Simulation
from motionphysics.sim.model import Model
from motionphysics.sim.solver import Solver, SolverConfig

DX = 1.0 / 16
DIMS = (17, 17, 17)
SUBSTEPS = 12
FRAME_DT = 4.0e-3  # dt = 3.3e-4 s: CFL 0.4 allows wave speeds up to 75 m/s
FRAMES = (1, 2)  # supervised frames -> 24 substeps back-propagated

CLASS_PARAMS = {
    "elastic": {"E": 4.0e4, "nu": 0.3},
    "plasticine": {"E": 4.0e4, "nu": 0.3, "tau_Y": 300.0},
    "metal": {"E": 4.0e4, "nu": 0.3, "tau_Y": 300.0},
    "foam": {"E": 4.0e4, "nu": 0.3, "eta": 20.0, "tau_Y": 300.0},
    "sand": {"E": 4.0e4, "nu": 0.3, "theta_fric": 30.0},
    "newtonian": {"mu": 20.0, "kappa": 4.0e4},
    "non_newtonian": {"mu": 1.0e4, "kappa": 4.0e4, "tau_Y": 100.0, "eta": 50.0, "n": 1.0},
}
"""Sim values per class: yield strains (~0.5-1 %) well below the ~6 % strain the initial
velocity imposes, so plastic flow is active and its parameters matter."""


def _block():
    """A 4 x 4 x 3 block of particles (48), spacing dx/2, around the grid centre."""
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(3), indexing="ij"), -1).reshape(
        -1, 3
    )
    x = 0.5 + (g - g.mean(axis=0)) * (DX / 2)
    return x.astype(np.float64)


def _sim(cls: str, gravity=(0.0, 0.0, -9.8), threads: int = 1) -> Simulation:
    x = _block()
    P = x.shape[0]
    mat = {"class": cls, "density": 100.0, **CLASS_PARAMS[cls]}
    model = Model.from_particles(
        np.full(P, (DX / 2) ** 3),
        mat,
        (0, 0, 0),
        DX,
        DIMS,
        gravity=gravity,
        requires_grad=True,
        positions=x,
    )
    state0 = model.state(x, requires_grad=True)
    solver = Solver(model, SolverConfig(threads=threads, min_particles_per_thread=1))
    return Simulation(model, solver, state0, SUBSTEPS, FRAME_DT, frames=3)


def _initial_velocity(x: np.ndarray) -> np.ndarray:
    """Shear + compression + spin about the block centre (deforms the block within 24 substeps)."""
    r = x - x.mean(axis=0)
    v = np.stack(
        [
            3.0 * r[:, 2] - 8.0 * r[:, 0],
            -6.0 * r[:, 1] + 2.0 * r[:, 0],
            5.0 * r[:, 0] - 4.0 * r[:, 2],
        ],
        -1,
    )
    return v + np.array([0.3, -0.2, 0.1])


def _loss_fn(sim: Simulation, seed: int = 0, grad_mode="full", window=8):
    rng = np.random.default_rng(seed)
    P = sim.model.particle_count
    wx = torch.tensor(rng.normal(size=(len(FRAMES), P, 3)), dtype=torch.float64)
    wF = torch.tensor(rng.normal(size=(len(FRAMES), P, 3, 3)), dtype=torch.float64)
    x0 = torch.tensor(_block(), dtype=torch.float64)
    v_rest = torch.tensor(_initial_velocity(_block()), dtype=torch.float32)

    def loss(params: dict[str, torch.Tensor], dv: torch.Tensor) -> torch.Tensor:
        xs, Fs = simulate(
            sim,
            params,
            frames=FRAMES,
            initial_velocity=v_rest + dv,
            grad_mode=grad_mode,
            window=window,
        )
        # displacement (not raw positions) keeps float32 round-off of x ~ 0.5 m out of the FD
        return ((xs.double() - x0) * wx).sum() * 10.0 + (Fs.double() * wF).sum()

    return loss


def _grads(sim, names, grad_mode="full", window=8):
    base = {k: float(v) for k, v in CLASS_PARAMS[sim_class(sim)].items()}
    base["density"] = 100.0
    loss = _loss_fn(sim, grad_mode=grad_mode, window=window)
    params = {k: torch.tensor(base[k], requires_grad=True) for k in names}
    dv = torch.zeros(3, requires_grad=True)
    L = loss(params, dv)
    L.backward()
    return loss, base, {k: float(p.grad) for k, p in params.items()}, dv.grad.numpy().copy()


def sim_class(sim) -> str:
    from motionphysics.config import MATERIAL_CLASSES

    return MATERIAL_CLASSES[int(sim.model.material_class.numpy()[0])]


def _fd_slope(f, h_max: float, pairs: int = 10) -> float:
    """Derivative of f at 0 from `pairs` symmetric pairs of steps h_max/pairs ... h_max.

    Least squares over the odd parts (f(h) - f(-h)) / 2 = b h + c h^3 (+ O(h^5)); b is the
    derivative. Why not one central difference: the float32 rollout's loss (~9) carries
    ~1e-5 (~1e-6 relative) of round-off noise that changes with any reordering of float
    operations, and a weakly sensitive parameter (foam eta: ~7e-5 per 1 % step) then moves a
    single 3 % central difference by several % from one code version to the next (measured
    -7.5 .. +2.9 % for foam eta). Twenty evaluations out to 10 % average the noise down
    (~0.09 sigma / (loss change per 1 % step), ~1 % for foam eta) and the h^3 term takes out
    the curvature that a lone 10 % step would leave (plasticine / metal E: +9 %); the FD
    estimates stayed within 3.1 % of the tape across the G2P and P2G kernel rewrites, so the
    5 % tolerance keeps room for yield-surface crossings and still catches a 10 % error."""
    h = h_max * np.arange(1, pairs + 1) / pairs
    y = np.array([(f(hi) - f(-hi)) / 2 for hi in h])
    # scaled columns keep the normal equations well conditioned
    X = np.stack([h / h_max, (h / h_max) ** 3], -1)
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    return float(coef[0] / h_max)


@pytest.mark.parametrize("cls", [*CLASS_PARAMS, "non_newtonian_n0.8"])
def test_full_gradient_matches_finite_differences(cls, monkeypatch):
    if cls == "non_newtonian_n0.8":  # the Newton-iterated Herschel-Bulkley branch
        cls = "non_newtonian"
        monkeypatch.setitem(CLASS_PARAMS, cls, {**CLASS_PARAMS[cls], "n": 0.8})
    sim = _sim(cls)
    names = [*CLASS_PARAMS[cls], "density"]
    loss, base, g, gv = _grads(sim, names)
    p0 = {n: torch.tensor(base[n]) for n in names}
    with torch.no_grad():
        for k in names:
            fd = _fd_slope(
                lambda d, k=k: float(loss({**p0, k: torch.tensor(base[k] + d)}, torch.zeros(3))),
                0.1 * base[k],
            )
            assert abs(g[k] - fd) <= 5e-2 * max(abs(fd), abs(g[k])) + 1e-9, (
                f"{cls}.{k}: tape {g[k]:.6g} vs FD {fd:.6g}"
            )
            assert abs(fd) * base[k] > 1e-3, (
                f"{cls}.{k}: loss insensitive (FD {fd:.3g}); test is vacuous"
            )
        for a in range(3):
            e = torch.eye(3)[a]
            fd = _fd_slope(lambda d, e=e: float(loss(p0, d * e)), 2e-2)
            assert abs(gv[a] - fd) <= 5e-2 * max(abs(fd), abs(gv[a])) + 1e-6, (
                f"{cls}.v0[{a}]: tape {gv[a]:.6g} vs FD {fd:.6g}"
            )


def test_truncated_modes():
    """last_substep differs from full; a window spanning every substep equals full."""
    sim = _sim("elastic")
    names = ["E", "nu", "density"]
    _, _, g_full, gv_full = _grads(sim, names)
    _, _, g_last, _ = _grads(sim, names, grad_mode="last_substep")
    _, _, g_win, gv_win = _grads(sim, names, grad_mode="window", window=FRAMES[-1] * SUBSTEPS)
    for k in names:
        # float32 accumulation order is the same in both paths; 1e-4 covers summation order
        assert g_win[k] == pytest.approx(g_full[k], rel=1e-4, abs=1e-9)
        assert abs(g_last[k] - g_full[k]) > 0.1 * abs(g_full[k]), k
    np.testing.assert_allclose(gv_win, gv_full, rtol=1e-4, atol=1e-6)


def test_per_particle_gradients_sum_to_scene_wide():
    sim = _sim("metal")
    loss = _loss_fn(sim)
    P = sim.model.particle_count
    E_scalar = torch.tensor(4.0e4, requires_grad=True)
    loss({"E": E_scalar}, torch.zeros(3)).backward()
    E_pp = torch.full((P,), 4.0e4, requires_grad=True)
    loss({"E": E_pp}, torch.zeros(3)).backward()
    assert E_pp.grad.shape == (P,)
    assert float(E_pp.grad.sum()) == pytest.approx(float(E_scalar.grad), rel=1e-4)
    # one particle's stiffness, against FD
    i = int(torch.argmax(E_pp.grad.abs()))
    h = 2.0e3  # 5 %: one particle's stiffness moves the loss little; smaller steps hit round-off
    with torch.no_grad():
        Ep, Em = E_pp.detach().clone(), E_pp.detach().clone()
        Ep[i] += h
        Em[i] -= h
        fd = (float(loss({"E": Ep}, torch.zeros(3))) - float(loss({"E": Em}, torch.zeros(3)))) / (
            2 * h
        )
    assert float(E_pp.grad[i]) == pytest.approx(fd, rel=1e-1)


def test_mixed_materials_gradients():
    """Two classes in one scene: gradients reach each class's own parameters only."""
    x = _block()
    P = x.shape[0]
    cls = np.where(x[:, 0] < 0.5, 0, 2)  # elastic | metal
    mat = {"class": cls, "density": 100.0, "E": 4.0e4, "nu": 0.3, "tau_Y": 300.0}
    model = Model.from_particles(
        np.full(P, (DX / 2) ** 3), mat, (0, 0, 0), DX, DIMS, requires_grad=True
    )
    sim = Simulation(
        model, Solver(model), model.state(x, requires_grad=True), SUBSTEPS, FRAME_DT, frames=3
    )
    loss = _loss_fn(sim)
    tau = torch.full((P,), 300.0, requires_grad=True)
    E = torch.full((P,), 4.0e4, requires_grad=True)
    loss({"tau_Y": tau, "E": E}, torch.zeros(3)).backward()
    assert torch.all(tau.grad[torch.from_numpy(cls == 0)] == 0)  # elastic particles ignore tau_Y
    assert torch.any(tau.grad[torch.from_numpy(cls == 2)] != 0)
    assert torch.all(E.grad != 0)


def test_stepwise_and_taped_backward_agree():
    """The memory-lean step-wise recomputation gives the same gradients as the taped span."""
    names = ["E", "nu", "tau_Y", "density"]
    sim = _sim("metal")
    _, _, g_taped, gv_taped = _grads(sim, names)
    sim.rollout.tape_memory = 0  # force the step-wise path
    _, _, g_step, gv_step = _grads(sim, names)
    for k in names:
        # same kernels, same order: equal up to float32 summation-order noise
        assert g_step[k] == pytest.approx(g_taped[k], rel=1e-4, abs=1e-12), k
    np.testing.assert_allclose(gv_step, gv_taped, rtol=1e-4, atol=1e-8)


def test_two_thread_chunks_give_the_same_gradients():
    """Threaded chunks (private P2G grids, private adjoint grids in backward) = one chunk."""
    names = ["E", "nu", "tau_Y", "density"]
    _, _, g1, gv1 = _grads(_sim("plasticine", threads=1), names)
    sim2 = _sim("plasticine", threads=2)
    assert sim2.solver.chunks == 2
    _, _, g2, gv2 = _grads(sim2, names)
    for k in names:
        # different float32 summation order of the grid sums only
        assert g2[k] == pytest.approx(g1[k], rel=1e-3, abs=1e-12), k
    np.testing.assert_allclose(gv2, gv1, rtol=1e-3, atol=1e-7)
