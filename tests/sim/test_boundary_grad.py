"""Gradients of every boundary kernel against central finite differences (float32, CPU).

Each check records, on one ``wp.Tape``, a plain Warp kernel that WRITES the array the
hook then modifies in place (like the grid update / G2P), the hook(s), and a nonlinear
loss kernel that READS the modified array (like G2P / a render loss). So the tests also
cover the in-place custom adjoint: no double counting of the overwritten values, and
gradients reaching both the upstream inputs and the learned parameters.

Tolerance: directional derivatives along random unit-variance directions with
eps = 1e-3. Every kernel is continuous and piecewise smooth in its inputs, so the FD
truncation error is at most (derivative jump) * eps at the few elements that straddle
a kink; the FD loss is summed in float64 on the host from float32 outputs (~1e3 terms,
round-off ~1e-7 relative each: ~1e-5 absolute, ~5e-3 after dividing by 2 eps). Directional derivatives are O(10), so rtol 1e-2 with
atol 2e-2 separates a correct adjoint from a wrong one (a missing or doubled term is
O(1) or more).
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from motionphysics.config import config_from_dict
from motionphysics.runtime import init_warp
from motionphysics.sim.boundary import BoundaryProgram

wp = init_warp()

LO = (-0.3, -0.3, -0.2)
DX = 0.1
DIMS = (6, 6, 6)
EPS = 1e-3
RTOL, ATOL = 1e-2, 2e-2


@wp.kernel
def _make_grid(u: wp.array3d(dtype=wp.vec3), g: wp.array3d(dtype=wp.vec3)):
    i, j, k = wp.tid()
    g[i, j, k] = 2.0 * u[i, j, k] + wp.vec3(0.1, -0.2, 0.05)


@wp.kernel
def _grid_loss(
    g: wp.array3d(dtype=wp.vec3), w: wp.array3d(dtype=wp.vec3), loss: wp.array(dtype=float)
):
    i, j, k = wp.tid()
    v = g[i, j, k]
    wp.atomic_add(loss, 0, wp.dot(w[i, j, k], v) + 0.5 * wp.dot(v, v))


@wp.kernel
def _fake_g2p(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    C: wp.array(dtype=wp.mat33),
    dt: float,
    x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    C_out: wp.array(dtype=wp.mat33),
):
    p = wp.tid()
    vn = 1.5 * v[p] + 0.1 * x[p]
    x_out[p] = x[p] + dt * vn
    v_out[p] = vn
    C_out[p] = 0.5 * C[p] + wp.outer(v[p], x[p])


@wp.kernel
def _particle_loss(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    C: wp.array(dtype=wp.mat33),
    wx: wp.array(dtype=wp.vec3),
    wv: wp.array(dtype=wp.vec3),
    wc: wp.array(dtype=wp.mat33),
    loss: wp.array(dtype=float),
):
    p = wp.tid()
    xp = x[p]
    vp = v[p]
    Cp = C[p]
    val = wp.dot(wx[p], xp) + wp.dot(wv[p], vp) + wp.ddot(wc[p], Cp)
    val = val + 5.0 * wp.dot(xp, xp) + 0.5 * wp.dot(vp, vp) + 0.5 * wp.ddot(Cp, Cp)
    wp.atomic_add(loss, 0, val)


def build(bcs=(), forces=(), x0=None):
    cfg = config_from_dict({"boundary_conditions": list(bcs), "forces": list(forces)})
    return BoundaryProgram.build(
        cfg.boundary_conditions, cfg.forces, x0=x0, domain_lo=LO, dx=DX, grid_dims=DIMS
    )


def directional_check(loss_fn, grads: dict, inputs: dict, rng):
    """Compare <grad, d> with central differences of loss_fn(inputs) along random d, per input."""
    for name, value in inputs.items():
        d = rng.normal(size=np.shape(value))
        plus = {**inputs, name: value + EPS * d}
        minus = {**inputs, name: value - EPS * d}
        fd = (loss_fn(plus) - loss_fn(minus)) / (2 * EPS)
        an = float(np.sum(grads[name] * d))
        assert an == pytest.approx(fd, rel=RTOL, abs=ATOL), (
            f"d loss / d {name}: adjoint {an}, FD {fd}"
        )


# ------------------------------------------------------------------------------ grid

GRID_CASES = {
    "clamp_grid": [
        {
            "type": "clamp_grid",
            "box": [[-0.3, -0.3, -0.2], [0.0, 0.3, 0.1]],
            "velocity": [0.4, -0.3, 0.2],
            "axis": [True, False, True],
        }
    ],
    "bounding_box": [{"type": "bounding_box", "padding": 2, "friction": 0.3}],
    "sticky": [{"type": "surface_collider", "mode": "sticky", "normal": [0.2, 0.1, 1.0]}],
    "slip": [{"type": "surface_collider", "mode": "slip", "normal": [0.2, 0.1, 1.0]}],
    "frictional": [
        {
            "type": "surface_collider",
            "mode": "frictional",
            "friction": 0.4,
            "normal": [0.2, 0.1, 1.0],
        }
    ],
    "cut": [
        {
            "type": "surface_collider",
            "mode": "cut",
            # damping acts 1.5 cells or more inside the box (nodes x = 0.2, y, z inner)
            "box": [[0.0, -0.3, -0.2], [0.5, 0.3, 0.3]],
            "damping": 0.3,
        }
    ],
    "chain": [
        {"type": "surface_collider", "friction": 0.5},
        {"type": "bounding_box", "padding": 2, "friction": 0.2},
        {
            "type": "clamp_grid",
            "box": [[0.1, -0.3, 0.1], [0.3, 0.3, 0.3]],
            "velocity": [0.0, 0.5, 0.0],
        },
    ],
}


@pytest.mark.parametrize("case", sorted(GRID_CASES))
def test_grid_condition_gradients_match_finite_differences(case):
    check_grid_case(case, region=None)


@pytest.mark.parametrize("case", ["chain", "frictional", "bounding_box"])
def test_grid_gradients_with_an_active_region(case):
    # The solver processes only the nodes around the particles: outside the region the
    # hook is the identity and the incoming gradient must pass through untouched.
    check_grid_case(case, region=((1, 0, 2), (4, 5, 3)))


def check_grid_case(case, region):
    rng = np.random.default_rng(zlib.crc32(case.encode()))
    prog = build(GRID_CASES[case], x0=np.zeros((1, 3)))
    u0 = rng.normal(size=(*DIMS, 3))
    w = wp.array(rng.normal(size=(*DIMS, 3)).astype(np.float32), dtype=wp.vec3)
    dt = 1e-3

    def run(values: dict, tape: bool):
        prog.set_param_values({k: v for k, v in values.items() if k != "u"})
        u = wp.array(values["u"].astype(np.float32), dtype=wp.vec3, requires_grad=tape)
        g = wp.zeros(DIMS, dtype=wp.vec3, requires_grad=tape)
        loss = wp.zeros(1, dtype=float, requires_grad=tape)
        rec = wp.Tape() if tape else None
        if rec is not None:
            rec.__enter__()
        try:
            wp.launch(_make_grid, DIMS, inputs=[u], outputs=[g])
            prog.apply_grid(None, g, 0.0, 0, dt, region=region)
            wp.launch(_grid_loss, DIMS, inputs=[g, w], outputs=[loss])
        finally:
            if rec is not None:
                rec.__exit__(None, None, None)
        last_grid[0] = g
        return u, loss, rec

    last_grid = [None]

    values = {"u": u0, **{k: v.astype(np.float64) for k, v in prog.param_values().items()}}
    u, loss, tape = run(values, tape=True)
    prog.zero_param_grads()
    tape.backward(loss=loss)
    grads = {"u": u.grad.numpy().astype(np.float64), **prog.param_grads()}
    # the taped forward (saved copies) and the untaped one (true in place) agree
    assert float(run(values, tape=False)[1].numpy()[0]) == pytest.approx(
        float(loss.numpy()[0]), rel=1e-6
    )
    w64 = w.numpy().astype(np.float64)

    def host_loss(vals):
        # float64 on the host: the float32 atomic sum of the taped loss is too coarse for FD
        u_, _, _ = run(vals, tape=False)
        del u_
        g = last_grid[0].numpy().astype(np.float64)
        return float(np.sum(w64 * g) + 0.5 * np.sum(g * g))

    directional_check(host_loss, grads, values, rng)
    if case in ("sticky", "slip"):
        assert prog.params == []
    else:
        assert all(np.any(g != 0) for k, g in grads.items() if k != "u"), grads


# ------------------------------------------------------------------------- particles

N = 40
PARTICLE_CASES = {
    "add_constant_force": (
        [],
        [
            {
                "type": "add_constant_force",
                "force": [0.5, -1.0, 2.0],
                "box": [[-0.3, -0.3, -0.2], [0.0, 0.3, 0.3]],
            }
        ],
    ),
    "add_impulse": (
        [],
        # (an impulse acts in the substep holding `start`: the one tested, t = 0.015 .. 0.025)
        [
            {
                "type": "add_impulse",
                "force": [3.0, 0.0, 1.0],
                "start": 0.02,
                "sphere": [[0.0, 0.0, 0.05], 0.1],
            }
        ],
    ),
    "translation": (
        [],
        [
            {
                "type": "force_particles_translation",
                "velocity": [0.3, 0.2, -0.1],
                "axis": [True, False, True],
                "box": [[-0.3, -0.3, -0.2], [0.3, 0.0, 0.3]],
            }
        ],
    ),
    "rotation": (
        [],
        [
            {
                "type": "force_particles_rotation",
                "center": [0.01, -0.02, 0.03],
                "axis_direction": [0.3, 1.0, 0.5],
                "angular_velocity": 2.5,
            }
        ],
    ),
    "release": ([], [{"type": "release_particles", "layers": 3, "start": 0.0, "end": 0.03}]),
    "cut": (
        [{"type": "surface_collider", "mode": "cut", "box": [[0.02, -0.3, -0.2], [0.3, 0.3, 0.3]]}],
        [],
    ),
    # collider planes project the particles behind them onto the plane after G2P
    "project_slip": (
        [{"type": "surface_collider", "mode": "slip", "point": [0, 0, -0.04]}],
        [],
    ),
    "project_frictional": (
        [{"type": "surface_collider", "mode": "frictional", "point": [0, 0, -0.04]}],
        [],
    ),
    "project_sticky": (
        [{"type": "surface_collider", "mode": "sticky", "point": [0, 0, -0.04]}],
        [],
    ),
    "chain": (
        [{"type": "surface_collider", "mode": "cut", "point": [0, 0, -0.04]}],
        [
            {"type": "add_constant_force", "force": [0.0, 0.0, -3.0]},
            {
                "type": "force_particles_rotation",
                "center": [0.0, 0.0, 0.0],
                "angular_velocity": -1.5,
                "sphere": [[0.0, 0.0, 0.0], 0.06],
            },
            {
                "type": "force_particles_translation",
                "velocity": [0.0, 0.0, 0.4],
                "axis": [False, False, True],
                "box": [[-0.3, -0.3, 0.02], [0.3, 0.3, 0.3]],
            },
            {
                "type": "release_particles",
                "layers": 2,
                "start": 0.0,
                "end": 0.04,
                "box": [[-0.3, -0.3, -0.2], [-0.02, 0.3, 0.3]],
            },
        ],
    ),
}


@pytest.mark.parametrize("case", sorted(PARTICLE_CASES))
def test_particle_hook_gradients_match_finite_differences(case):
    rng = np.random.default_rng(zlib.crc32(case.encode()))
    x0 = rng.uniform(-0.08, 0.08, size=(N, 3))
    # Removal by a cut is a jump in x; keep particles >= 0.01 away from the cut surfaces
    # (x = 0.02, z = -0.04) so the FD perturbations never cross them.
    for _ in range(100):
        bad = (np.abs(x0[:, 0] - 0.02) < 0.01) | (np.abs(x0[:, 2] + 0.04) < 0.01)
        if not bad.any():
            break
        x0[bad] = rng.uniform(-0.08, 0.08, size=(int(bad.sum()), 3))
    bcs, forces = PARTICLE_CASES[case]
    prog = build(bcs, forces, x0=x0)
    dt, t = 0.01, 0.015  # mid-window: releases half done
    wx, wv = (wp.array(rng.normal(size=(N, 3)).astype(np.float32), dtype=wp.vec3) for _ in range(2))
    wc = wp.array(rng.normal(size=(N, 3, 3)).astype(np.float32), dtype=wp.mat33)
    active0 = np.ones(N, np.float32)

    def run(values: dict, tape: bool):
        prog.set_param_values({k: v for k, v in values.items() if k not in ("x", "v", "C")})
        kw = {"requires_grad": tape}
        x = wp.array(values["x"].astype(np.float32), dtype=wp.vec3, **kw)
        v = wp.array(values["v"].astype(np.float32), dtype=wp.vec3, **kw)
        C = wp.array(values["C"].astype(np.float32), dtype=wp.mat33, **kw)
        s_in = _State(x, v, C, wp.array(active0, dtype=float))
        s_out = _State(
            wp.zeros(N, dtype=wp.vec3, **kw),
            wp.zeros(N, dtype=wp.vec3, **kw),
            wp.zeros(N, dtype=wp.mat33, **kw),
            wp.zeros(N, dtype=float),
        )
        loss = wp.zeros(1, dtype=float, requires_grad=tape)
        rec = wp.Tape() if tape else None
        if rec is not None:
            rec.__enter__()
        try:
            prog.apply_pre_p2g(None, s_in, t, 1, dt)
            wp.launch(
                _fake_g2p,
                N,
                inputs=[s_in.x, s_in.v, s_in.C, dt],
                outputs=[s_out.x, s_out.v, s_out.C],
            )
            prog.apply_post_g2p(None, s_in, s_out, t, 1, dt)
            wp.launch(
                _particle_loss, N, inputs=[s_out.x, s_out.v, s_out.C, wx, wv, wc], outputs=[loss]
            )
        finally:
            if rec is not None:
                rec.__exit__(None, None, None)
        return s_in, s_out, loss, rec

    values = {
        "x": x0,
        "v": rng.normal(size=(N, 3)),
        "C": rng.normal(size=(N, 3, 3)),
        **{k: v.astype(np.float64) for k, v in prog.param_values().items()},
    }
    s_in, s_out, loss, tape = run(values, tape=True)
    if case in ("cut", "chain"):
        removed = s_out.active.numpy() == 0
        assert 0 < removed.sum() < N  # the case really exercises removal
    if case.startswith("project"):
        on_plane = np.abs(s_out.x.numpy()[:, 2] + 0.04) < 1e-6
        assert 0 < on_plane.sum() < N  # the case really exercises the projection
    prog.zero_param_grads()
    tape.backward(loss=loss)
    grads = {
        "x": s_in.x.grad.numpy().astype(np.float64),
        "v": s_in.v.grad.numpy().astype(np.float64),
        "C": s_in.C.grad.numpy().astype(np.float64),
        **prog.param_grads(),
    }
    assert float(run(values, tape=False)[2].numpy()[0]) == pytest.approx(
        float(loss.numpy()[0]), rel=1e-6
    )
    wx64, wv64, wc64 = (a.numpy().astype(np.float64) for a in (wx, wv, wc))

    def host_loss(vals):
        # float64 on the host (same formula as _particle_loss): FD needs more than float32 sums
        _, out, _, _ = run(vals, tape=False)
        x, v, C = (a.numpy().astype(np.float64) for a in (out.x, out.v, out.C))
        return float(
            np.sum(wx64 * x)
            + np.sum(wv64 * v)
            + np.sum(wc64 * C)
            + 5.0 * np.sum(x * x)
            + 0.5 * np.sum(v * v)
            + 0.5 * np.sum(C * C)
        )

    directional_check(host_loss, grads, values, rng)
    for k, g in grads.items():
        if k.startswith("forces"):
            assert np.any(g != 0), f"no gradient reached {k}"


class _State:
    def __init__(self, x, v, C, active):
        self.x, self.v, self.C, self.active = x, v, C, active
