"""The recorded (taped) forward: what it keeps alive for the backward, and that it gives
the untaped forward's states bit for bit."""

from __future__ import annotations

import gc

import numpy as np
from test_solver import ELASTIC, _cfg, _hooked_sim, _scene

from motionphysics.sim.build import build_simulation
from motionphysics.sim.solver import Solver
from motionphysics.sim.state import State


def _elastic_sim():
    cfg = _cfg(frames=4, initial_velocity=(0.5, 0.0, -2.0))
    return build_simulation(_scene(n_side=4), cfg, ELASTIC, requires_grad=True)


def _tracked_per_substep(sim, frames: int = 4) -> float:
    """Objects Python's garbage collector tracks that a recording forward leaves alive
    (its tapes, kept for the backward), per recorded substep."""
    ro = sim.rollout
    ro.tape_memory = 1 << 34
    p = sim.model.particle_count
    adj = {frames - 1: {"x": np.ones((p, 3), np.float32)}}
    for _ in range(2):  # warm: buffers, pools, kernels
        ro.forward(sim.state0, frames, record_tapes=True, check=False)
        sim.model.zero_grad()
        ro.backward(adj)
    gc.collect()
    before = len(gc.get_objects())
    ro.forward(sim.state0, frames, record_tapes=True, check=False)
    assert ro.kept_frames == list(range(1, frames))
    gc.collect()
    return (len(gc.get_objects()) - before) / ((frames - 1) * ro.substeps)


def test_recorded_substeps_keep_few_objects_for_the_garbage_collector():
    """A recorded substep's adjoints are kept as a few plain records, not closures (~85
    tracked objects per substep before: at 1,500 particles and 3,500 recorded substeps the
    collector's passes over them were a third of the recorded forward)."""
    assert _tracked_per_substep(_elastic_sim()) < 25  # 12-14 (elastic stress, P2G, grid, G2P)
    # every kind of hook recording: ~40 (was ~200)
    assert _tracked_per_substep(_hooked_sim()) < 80


def _frames(sim, record_tapes: bool, frames: int = 4) -> list[dict[str, np.ndarray]]:
    ro = sim.rollout
    ro.tape_memory = 1 << 34
    out = []
    orig = ro.check

    def keep(state: State, frame: int) -> None:
        out.append(state.numpy())
        orig(state, frame)

    ro.check = keep
    try:
        ro.forward(sim.state0, frames, record_tapes=record_tapes)
    finally:
        ro.check = orig
    assert ro.kept_frames == (list(range(1, frames)) if record_tapes else [])
    return out


def test_taped_and_untaped_forward_give_bit_identical_states():
    """Every field of every frame (x, v, C, F, ep, active), with and without hooks."""
    for make in (_elastic_sim, _hooked_sim):
        sim = make()
        plain, taped = _frames(sim, False), _frames(sim, True)
        assert len(plain) == len(taped) == 3
        for a, b in zip(plain, taped, strict=True):
            for name in a:
                np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        assert not np.array_equal(plain[-1]["x"], sim.state0.x.numpy())


def test_recorded_fused_stress_and_p2g_give_the_two_kernels_gradients():
    """A recorded all-elastic substep runs the fused stress + P2G kernel (storing the affine
    matrices and rotations the two hand-written adjoints read): the same states and
    gradients as the two kernels (``SolverConfig.fuse_elastic_p2g=False``)."""
    import dataclasses

    out = []
    for fuse in (True, False):
        sim = _hooked_sim()
        sim.solver.config = dataclasses.replace(sim.solver.config, fuse_elastic_p2g=fuse)
        ro = sim.rollout
        ro.tape_memory = 1 << 34
        p = sim.model.particle_count
        rng = np.random.default_rng(7)
        adj = {f: {"x": rng.normal(size=(p, 3)), "F": rng.normal(size=(p, 3, 3))} for f in (1, 3)}
        res = ro.forward(sim.state0, 4, record_tapes=True, check=False)
        assert ro.kept_frames == [1, 2, 3]
        sim.model.zero_grad()
        sim.model.boundary.zero_param_grads()
        a0 = ro.backward(adj)
        g = {k: a.grad.numpy().copy() for k, a in sim.model.params.items()}
        g.update(sim.model.boundary.param_grads())
        out.append((res.xs, res.Fs, a0.x.numpy().copy(), a0.v.numpy().copy(), g))
    (xs1, Fs1, ax1, av1, g1), (xs0, Fs0, ax0, av0, g0) = out
    np.testing.assert_array_equal(xs1, xs0)
    np.testing.assert_array_equal(Fs1, Fs0)
    np.testing.assert_array_equal(ax1, ax0)
    np.testing.assert_array_equal(av1, av0)
    assert np.any(g0["E"] != 0)
    for k in g0:
        np.testing.assert_array_equal(g1[k], g0[k], err_msg=k)


def test_a_grid_recorded_again_on_a_clean_region_is_not_zeroed_again(monkeypatch):
    """A complete backward leaves each recorded grid's node velocity adjoint zero on its
    region (``Grid.clean``): the next recording of the same substeps (an iteration with
    the same regions) skips zeroing it, with the same gradients; a grid whose backward did
    not run to its end is zeroed again."""
    from motionphysics.sim import kernels as K
    from motionphysics.sim.launch import Rebinds

    sim = _elastic_sim()
    ro = sim.rollout
    ro.tape_memory = 1 << 34
    p = sim.model.particle_count
    rng = np.random.default_rng(2)
    adj = {f: {"x": rng.normal(size=(p, 3)), "F": rng.normal(size=(p, 3, 3))} for f in (1, 3)}
    zeroes = []
    launch = Rebinds.launch  # the solver's launches of recorded substeps (sim.launch)

    def counted(self, kernel, *a, **k):
        if kernel is K._zero_region_vec3:
            zeroes.append(1)
        return launch(self, kernel, *a, **k)

    monkeypatch.setattr(Rebinds, "launch", counted)

    def iteration():
        zeroes.clear()
        ro.forward(sim.state0, 4, record_tapes=True, check=False)
        n = len(zeroes)
        sim.model.zero_grad()
        ro.backward(adj)
        return n, {k: a.grad.numpy().copy() for k, a in sim.model.params.items()}

    n1, g1 = iteration()
    n2, g2 = iteration()
    assert n1 >= 3 * ro.substeps  # fresh grids: every recorded substep zeroes its region
    assert n2 == 0  # same regions, each left clean by the complete backward
    for k in g1:
        np.testing.assert_array_equal(g2[k], g1[k], err_msg=k)
    # a recording whose backward stopped part-way: its grids are zeroed again
    ro.forward(sim.state0, 4, record_tapes=True, check=False)
    tape, states, bufs = ro._kept[3]
    bufs["dirty"] = len(states)  # as Rollout._backward_span_taped marks a span it starts
    states[-1].x.grad.assign(rng.normal(size=(p, 3)).astype(np.float32))
    # the later substeps' part, from a G2P adjoint on: its substep's grid update adjoint,
    # which would consume the node velocity adjoint G2P's scattered, does not run
    g2p = [
        i
        for i, r in enumerate(tape.launches)
        if isinstance(r, tuple) and r[0] is Solver._g2p_backward
    ]
    tape.launches = tape.launches[g2p[len(g2p) // 2] :]
    tape.backward()
    tape.launches = []
    assert any(g.clean is None for g in bufs["tgrids"])
    n3, g3 = iteration()
    assert n3 > 0
    for k in g1:
        np.testing.assert_array_equal(g3[k], g1[k], err_msg=k)
