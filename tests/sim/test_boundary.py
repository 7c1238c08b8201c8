"""Boundary conditions and forces: validation, semantics, and float64 NumPy reference twins.

Everything runs on tiny synthetic grids / particle sets through the public hooks of
``BoundaryProgram`` (no solver needed). Forward results are compared with NumPy
float64 twins at atol 1e-5: values are O(1) and each kernel does a handful of float32
operations (relative round-off ~1e-7 per operation).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from motionphysics.config import config_from_dict
from motionphysics.errors import UserInputError
from motionphysics.runtime import init_warp
from motionphysics.sim.boundary import BoundaryProgram, particle_bounds

wp = init_warp()

LO = (-0.5, -0.5, -0.25)
DX = 0.125
DIMS = (9, 9, 9)  # nodes; the domain spans [-0.5, 0.5] x [-0.5, 0.5] x [-0.25, 0.75]
ATOL = 1e-5


def program(bcs=(), forces=(), x0=None, dims=DIMS):
    cfg = config_from_dict({"boundary_conditions": list(bcs), "forces": list(forces)})
    if x0 is None:
        x0 = particles()
    return BoundaryProgram.build(
        cfg.boundary_conditions, cfg.forces, x0=x0, domain_lo=LO, dx=DX, grid_dims=dims
    )


def particles(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 0.4], size=(n, 3))


def node_positions(dims=DIMS):
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in dims], indexing="ij"), axis=-1)
    return np.asarray(LO) + DX * idx  # (nx, ny, nz, 3)


def grid_array(v):
    return wp.array(np.asarray(v, dtype=np.float32), dtype=wp.vec3)


def random_grid(seed=1, dims=DIMS):
    return np.random.default_rng(seed).normal(size=(*dims, 3))


def state(x, v=None, C=None, active=None):
    n = len(x)
    v = np.zeros((n, 3)) if v is None else v
    C = np.zeros((n, 3, 3)) if C is None else C
    active = np.ones(n) if active is None else active
    return SimpleNamespace(
        x=wp.array(np.asarray(x, np.float32), dtype=wp.vec3),
        v=wp.array(np.asarray(v, np.float32), dtype=wp.vec3),
        C=wp.array(np.asarray(C, np.float32), dtype=wp.mat33),
        active=wp.array(np.asarray(active, np.float32), dtype=float),
    )


# ----------------------------------------------------------------- reference twins


def ref_coulomb(vt, vn_abs, mu):
    lt = np.linalg.norm(vt, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(lt > mu * vn_abs[..., None], 1.0 - mu * vn_abs[..., None] / lt, 0.0)
    return vt * scale


def ref_collider(v, point, normal, mode, mu):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    d = (node_positions(v.shape[:3]) - np.asarray(point)) @ n
    contact = d <= 1e-4 * DX
    vn = v @ n
    vt = v - vn[..., None] * n
    if mode == "sticky":
        new = np.zeros_like(v)
    elif mode == "slip":
        new = np.where((vn < 0)[..., None], vt, v)
    else:
        new = np.where((vn < 0)[..., None], ref_coulomb(vt, -vn, mu), v)
    return np.where(contact[..., None], new, v)


def ref_bounding_box(v, padding, mu):
    out = v.copy()
    removed = np.zeros_like(v)
    for a in range(3):
        n = v.shape[a]
        idx = np.arange(n).reshape([-1 if b == a else 1 for b in range(3)])
        low = (idx < padding) & (v[..., a] < 0)
        high = (idx >= n - padding) & (v[..., a] > 0)
        hit = low | high
        removed[..., a] = np.where(hit, v[..., a], 0.0)
        out[..., a] = np.where(hit, 0.0, v[..., a])
    if mu > 0:
        r = np.linalg.norm(removed, axis=-1)
        out = np.where((r > 0)[..., None], ref_coulomb(out, r, mu), out)
    return out


# ---------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("bcs", "forces", "fragment"),
    [
        ([{"type": "surface_collider", "normal": [0, 0, 0]}], [], "boundary_conditions[0].normal"),
        (
            [{"type": "bounding_box"}, {"type": "clamp_grid", "box": [[1, 0, 0], [0, 1, 1]]}],
            [],
            "boundary_conditions[1].box",
        ),
        (
            [{"type": "clamp_grid", "box": [[5, 5, 5], [6, 6, 6]]}],
            [],
            "boundary_conditions[0].box: contains no grid node",
        ),
        (
            [{"type": "clamp_grid", "box": [[0, 0, 0], [1, 1, 1]], "axis": [False, False, False]}],
            [],
            "boundary_conditions[0].axis",
        ),
        (
            [{"type": "surface_collider", "mode": "sticky", "friction": 0.5}],
            [],
            "boundary_conditions[0].friction",
        ),
        (
            [{"type": "surface_collider", "mode": "slip", "box": [[0, 0, 0], [1, 1, 1]]}],
            [],
            "boundary_conditions[0].box",
        ),
        ([{"type": "bounding_box", "padding": 5}], [], "boundary_conditions[0].padding"),
        ([{"type": "bounding_box", "start": 1.0, "end": 0.5}], [], "boundary_conditions[0].end"),
        (
            [],
            [{"type": "add_impulse", "force": [0, 0, 1], "box": [[2, 2, 2], [3, 3, 3]]}],
            "forces[0].box: selects no particles",
        ),
        (
            [],
            [
                {"type": "add_impulse", "force": [0, 0, 1]},
                {"type": "add_impulse", "force": [0, 0, 1], "sphere": [[2, 2, 2], 0.1]},
            ],
            "forces[1].sphere",
        ),
        (
            [],
            [{"type": "add_impulse", "force": [0, 0, 1], "sphere": [[0, 0, 0], 0.0]}],
            "forces[0].sphere",
        ),
        (
            [],
            [
                {
                    "type": "add_impulse",
                    "force": [0, 0, 1],
                    "unit": "substeps",
                    "start": 0.5,
                    "end": 2,
                }
            ],
            "forces[0]",
        ),
        (
            [],
            [
                {
                    "type": "force_particles_rotation",
                    "center": [0, 0, 0],
                    "axis_direction": [0, 0, 0],
                    "angular_velocity": 1.0,
                }
            ],
            "forces[0].axis_direction",
        ),
        (
            [],
            [
                {
                    "type": "force_particles_translation",
                    "velocity": [1, 0, 0],
                    "axis": [False, False, False],
                }
            ],
            "forces[0].axis",
        ),
        ([], [{"type": "release_particles", "layers": 4}], "forces[0].end"),
    ],
)
def test_bad_entries_raise_user_input_error_naming_the_entry(bcs, forces, fragment):
    with pytest.raises(UserInputError) as err:
        program(bcs, forces)
    msg = str(err.value)
    assert fragment in msg
    assert "\n" not in msg


def test_plain_mappings_are_validated_like_the_config():
    x = particles(20)
    prog = BoundaryProgram.build(
        [{"type": "surface_collider", "mode": "slip"}],
        [{"type": "add_impulse", "force": [0, 0, 1]}],
        x0=x,
        domain_lo=LO,
        dx=DX,
        grid_dims=DIMS,
    )
    assert [p.name for p in prog.params] == ["forces[0].force"]
    with pytest.raises(UserInputError, match=r"^forces\[0\]\.force"):
        BoundaryProgram.build(
            [],
            [{"type": "add_impulse", "force": [0, 1]}],
            x0=x,
            domain_lo=LO,
            dx=DX,
            grid_dims=DIMS,
        )
    with pytest.raises(UserInputError, match=r"^boundary_conditions\[0\]"):
        BoundaryProgram.build([{"type": "wall"}], [], x0=x, domain_lo=LO, dx=DX, grid_dims=DIMS)


def test_params_are_named_and_settable():
    prog = program(
        [
            {"type": "surface_collider", "friction": 0.4},
            {"type": "bounding_box", "friction": 0.1},
            {"type": "surface_collider", "mode": "slip"},
        ],
        [
            {"type": "add_constant_force", "force": [1, 2, 3]},
            {"type": "force_particles_rotation", "center": [0, 0, 0], "angular_velocity": -5.0},
        ],
    )
    assert [p.name for p in prog.params] == [
        "boundary_conditions[0].friction",
        "boundary_conditions[1].friction",
        "forces[0].force",
        "forces[1].angular_velocity",
    ]
    vals = prog.param_values()
    np.testing.assert_allclose(vals["forces[0].force"], [1, 2, 3])
    np.testing.assert_allclose(vals["forces[1].angular_velocity"], [-5.0])
    prog.set_param_values(
        {"forces[0].force": np.array([0.0, 0.0, -1.0]), "boundary_conditions[0].friction": 0.9}
    )
    np.testing.assert_allclose(prog.param("forces[0].force").value(), [0, 0, -1])
    np.testing.assert_allclose(
        prog.param("boundary_conditions[0].friction").value(), [0.9], rtol=1e-6
    )
    with pytest.raises(KeyError):
        prog.param("forces[7].force")
    with pytest.raises(ValueError):
        prog.set_param_values({"forces[0].force": [1.0, 2.0]})


# ------------------------------------------------------------------ grid conditions


@pytest.mark.parametrize("mode", ["sticky", "slip", "frictional"])
def test_surface_collider_matches_reference(mode):
    point, normal, mu = (0.0, 0.1, 0.0), (0.3, -0.2, 1.0), 0.4
    bc = {"type": "surface_collider", "point": list(point), "normal": list(normal), "mode": mode}
    if mode == "frictional":
        bc["friction"] = mu
    prog = program([bc])
    v = random_grid()
    g = grid_array(v)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)
    np.testing.assert_allclose(g.numpy(), ref_collider(v, point, normal, mode, mu), atol=ATOL)


def test_collider_contact_semantics_on_ground():
    # Ground z = 0: node layer k = 2 sits exactly on it (lo_z = -0.25, dx = 0.125).
    v = np.zeros((*DIMS, 3))
    v[..., :] = (3.0, -1.0, -2.0)  # moving into the ground, |vt| = sqrt(10) > mu |vn|
    v[:, :, 1, :] = (0.2, 0.0, -2.0)  # |vt| = 0.2 < mu |vn| = 1.0: static friction
    v[:, :, 0, :] = (1.0, 0.0, 2.0)  # separating: untouched
    z = node_positions()[..., 2]
    for mode in ("sticky", "slip", "frictional"):
        bc = {"type": "surface_collider", "mode": mode}
        if mode == "frictional":
            bc["friction"] = 0.5
        prog = program([bc])
        g = grid_array(v)
        prog.apply_grid(None, g, 0.0, 0, 1e-3)
        out = g.numpy()
        above = z > 1e-6
        np.testing.assert_array_equal(
            out[above], v[above].astype(np.float32)
        )  # no contact above the plane
        if mode == "sticky":
            np.testing.assert_array_equal(out[~above], 0.0)
        elif mode == "slip":
            np.testing.assert_allclose(
                out[:, :, 2], np.broadcast_to([3.0, -1.0, 0.0], out[:, :, 2].shape), atol=ATOL
            )
            np.testing.assert_allclose(
                out[:, :, 1], np.broadcast_to([0.2, 0.0, 0.0], out[:, :, 1].shape), atol=ATOL
            )
            np.testing.assert_allclose(
                out[:, :, 0], np.broadcast_to([1.0, 0.0, 2.0], out[:, :, 0].shape), atol=ATOL
            )
        else:
            # Coulomb: |vt| reduced by mu |vn| = 1 along its direction; static when |vt| <= 1.
            vt = np.array([3.0, -1.0]) * (1.0 - 1.0 / np.sqrt(10.0))
            np.testing.assert_allclose(
                out[:, :, 2, :2], np.broadcast_to(vt, out[:, :, 2, :2].shape), atol=ATOL
            )
            np.testing.assert_allclose(out[:, :, 2, 2], 0.0, atol=ATOL)
            np.testing.assert_allclose(out[:, :, 1], 0.0, atol=ATOL)
            np.testing.assert_allclose(
                out[:, :, 0], np.broadcast_to([1.0, 0.0, 2.0], out[:, :, 0].shape), atol=ATOL
            )


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_bounding_box_matches_reference_and_blocks_outward_motion(friction):
    prog = program([{"type": "bounding_box", "padding": 3, "friction": friction}])
    v = 2.0 * random_grid(seed=3)
    g = grid_array(v)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)
    out = g.numpy()
    np.testing.assert_allclose(out, ref_bounding_box(v, 3, friction), atol=ATOL)
    assert np.all(out[:3, :, :, 0] >= 0) and np.all(out[-3:, :, :, 0] <= 0)
    assert np.all(out[:, :3, :, 1] >= 0) and np.all(out[:, -3:, :, 1] <= 0)
    assert np.all(out[:, :, :3, 2] >= 0) and np.all(out[:, :, -3:, 2] <= 0)
    np.testing.assert_array_equal(out[3:-3, 3:-3, 3:-3], v[3:-3, 3:-3, 3:-3].astype(np.float32))


def test_clamp_grid_sets_velocity_on_selected_axes_inside_box_only():
    box = [[-0.26, -0.5, 0.0], [0.0, 0.5, 0.25]]
    prog = program(
        [
            {
                "type": "clamp_grid",
                "box": box,
                "velocity": [0.5, -1.0, 2.0],
                "axis": [True, False, True],
            }
        ]
    )
    v = random_grid(seed=4)
    g = grid_array(v)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)
    out = g.numpy()
    p = node_positions()
    inside = np.all((p >= np.array(box[0]) - 1e-6) & (p <= np.array(box[1]) + 1e-6), axis=-1)
    assert inside.sum() == 3 * 9 * 3
    np.testing.assert_allclose(out[inside][:, 0], 0.5, atol=ATOL)
    np.testing.assert_allclose(out[inside][:, 2], 2.0, atol=ATOL)
    np.testing.assert_allclose(out[inside][:, 1], v[inside][:, 1], atol=ATOL)
    np.testing.assert_allclose(out[~inside], v[~inside], atol=ATOL)


def test_cut_damps_grid_in_box_and_removes_particles_for_good():
    x = np.array([[0.1, 0.0, 0.2], [-0.1, 0.0, 0.2], [0.3, 0.0, 0.3]])
    box = [[0.0, -0.5, 0.0], [0.5, 0.5, 0.5]]
    prog = program(
        [
            {
                "type": "surface_collider",
                "mode": "cut",
                "box": box,
                "damping": 0.75,
                "start": 0.0,
                "end": 0.01,
            }
        ],
        x0=x,
    )
    assert prog.has_cut
    v = random_grid(seed=5)
    g = grid_array(v)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)
    p = node_positions()
    # damped: the nodes 1.5 cells or more inside the box (the nodes nearer its surface
    # carry mass of the material outside, which the damping held up; issue 15)
    depth = 1.5 * DX
    inside = np.all(
        (p >= np.array(box[0]) + depth - 1e-6) & (p <= np.array(box[1]) - depth + 1e-6), axis=-1
    )
    assert inside.any()
    np.testing.assert_allclose(g.numpy()[inside], 0.25 * v[inside], atol=ATOL)
    np.testing.assert_allclose(g.numpy()[~inside], v[~inside], atol=ATOL)

    s_in = state(x)
    moved = x + 0.01
    s_out = state(moved, v=np.ones((3, 3)), C=np.ones((3, 3, 3)), active=np.array([1.0, 0.0, 1.0]))
    prog.apply_post_g2p(None, s_in, s_out, 0.0, 0, 1e-3)
    np.testing.assert_array_equal(s_out.active.numpy(), [0.0, 1.0, 0.0])  # from state_in's mask
    np.testing.assert_allclose(s_out.x.numpy()[[0, 2]], x[[0, 2]], atol=ATOL)  # held in place
    np.testing.assert_array_equal(s_out.v.numpy()[[0, 2]], 0.0)
    np.testing.assert_array_equal(s_out.C.numpy()[[0, 2]], 0.0)
    np.testing.assert_allclose(s_out.x.numpy()[1], moved[1], atol=ATOL)

    # After the window: nothing new is removed, removed ones stay removed and frozen.
    s_in2 = state(
        np.array([[0.1, 0.0, 0.2], [0.2, 0.0, 0.2], [0.3, 0.0, 0.3]]), active=s_out.active.numpy()
    )
    s_out2 = state(s_in2.x.numpy() + 0.02, v=np.ones((3, 3)))
    prog.apply_post_g2p(None, s_in2, s_out2, 0.5, 500, 1e-3)
    np.testing.assert_array_equal(s_out2.active.numpy(), [0.0, 1.0, 0.0])
    np.testing.assert_allclose(s_out2.x.numpy()[1], s_in2.x.numpy()[1] + 0.02, atol=ATOL)
    np.testing.assert_allclose(s_out2.x.numpy()[0], s_in2.x.numpy()[0], atol=ATOL)


def test_cut_without_box_uses_half_space_behind_plane():
    x = np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.3]])
    prog = program(
        [{"type": "surface_collider", "mode": "cut", "point": [0, 0, 0.2], "normal": [0, 0, 1]}],
        x0=x,
    )
    s_in, s_out = state(x), state(x + 0.01)
    prog.apply_post_g2p(None, s_in, s_out, 0.0, 0, 1e-3)
    np.testing.assert_array_equal(s_out.active.numpy(), [0.0, 1.0])


def test_grid_conditions_apply_in_config_order():
    # clamp then sticky ground: the clamped nodes on the ground end at 0; reversed: clamp wins.
    clamp = {
        "type": "clamp_grid",
        "box": [[-0.5, -0.5, -0.25], [0.5, 0.5, 0.0]],
        "velocity": [1, 1, 1],
    }
    ground = {"type": "surface_collider", "mode": "sticky"}
    v = random_grid(seed=6)
    for order, expected in (([clamp, ground], 0.0), ([ground, clamp], 1.0)):
        g = grid_array(v)
        program(order).apply_grid(None, g, 0.0, 0, 1e-3)
        np.testing.assert_allclose(g.numpy()[:, :, :3], expected, atol=ATOL)


# ----------------------------------------------------------------------- time windows


def test_time_windows_start_and_stop_on_time_in_seconds_and_substeps():
    x = particles(10)
    dt = 0.0025
    seconds = program(
        forces=[{"type": "add_impulse", "force": [0, 0, 1], "start": 0.01, "end": 0.02}], x0=x
    )
    substeps = program(
        forces=[
            {"type": "add_impulse", "force": [0, 0, 1], "start": 3, "end": 5, "unit": "substeps"}
        ],
        x0=x,
    )
    for prog, expected in ((seconds, [4, 5, 6, 7]), (substeps, [3, 4])):
        acted = []
        for s in range(12):
            s_in, s_out = state(x), state(x)
            prog.apply_post_g2p(None, s_in, s_out, s * dt, s, dt)
            if np.any(s_out.v.numpy() != 0):
                acted.append(s)
        assert acted == expected


def test_grid_condition_window():
    prog = program([{"type": "surface_collider", "mode": "sticky", "start": 0.5, "end": 1.0}])
    v = random_grid(seed=7)
    for t, changed in ((0.49, False), (0.5, True), (0.99, True), (1.0, False)):
        g = grid_array(v)
        prog.apply_grid(None, g, t, int(t / 1e-3), 1e-3)
        assert (not np.allclose(g.numpy(), v.astype(np.float32))) == changed


# ------------------------------------------------------------------ particle forces


def test_constant_force_selects_by_box_and_sphere_and_integrates_like_gravity():
    x = particles(300, seed=2)
    box = [[-0.2, -0.2, 0.0], [0.0, 0.2, 0.4]]
    sphere = [[0.1, 0.1, 0.2], 0.12]
    prog = program(
        forces=[
            {"type": "add_constant_force", "force": [1.0, 0.0, 0.0], "box": box},
            {"type": "add_constant_force", "force": [0.0, 0.0, -2.0], "sphere": sphere},
        ],
        x0=x,
    )
    in_box = np.all((x >= box[0]) & (x <= box[1]), axis=1)
    in_sphere = np.linalg.norm(x - sphere[0], axis=1) <= sphere[1]
    assert prog.selected == {"forces[0]": int(in_box.sum()), "forces[1]": int(in_sphere.sum())}
    assert 0 < in_box.sum() < 300 and 0 < in_sphere.sum() < 300
    dt = 0.01
    v0 = np.random.default_rng(0).normal(size=(300, 3))
    s_in, s_out = state(x), state(x, v=v0)
    prog.apply_post_g2p(None, s_in, s_out, 0.0, 0, dt)
    acc = in_box[:, None] * np.array([1.0, 0, 0]) + in_sphere[:, None] * np.array([0, 0, -2.0])
    np.testing.assert_allclose(s_out.v.numpy(), v0 + dt * acc, atol=ATOL)
    np.testing.assert_allclose(s_out.x.numpy(), x + dt * dt * acc, atol=ATOL)


def test_particles_never_leave_the_grid_under_forces():
    x = particles(50)
    prog = program(
        forces=[
            {"type": "add_constant_force", "force": [1e4, -1e4, 1e4]},
            {
                "type": "force_particles_translation",
                "velocity": [0, 0, -500.0],
                "axis": [False, False, True],
                "sphere": [[0, 0, 0.2], 0.1],
            },
        ],
        x0=x,
    )
    x_min, x_max = particle_bounds(LO, DX, DIMS)
    s_in = state(x)
    for s in range(20):
        s_out = state(s_in.x.numpy(), v=s_in.v.numpy())
        prog.apply_post_g2p(None, s_in, s_out, s * 0.01, s, 0.01)
        s_in = s_out
        xs = s_out.x.numpy()
        assert np.all(xs >= np.array(x_min) - 1e-6) and np.all(xs <= np.array(x_max) + 1e-6)


def test_translation_imposes_velocity_and_motion_on_masked_axes():
    x = particles(40) + np.array([0.0, 0.0, 0.05])  # away from the clamp box of particle_bounds
    dt = 0.01
    prog = program(
        forces=[
            {
                "type": "force_particles_translation",
                "velocity": [0.3, 0.7, -0.2],
                "axis": [True, False, True],
            }
        ],
        x0=x,
    )
    v_in = np.random.default_rng(3).normal(size=(40, 3))
    s_in = state(x, v=v_in)
    prog.apply_pre_p2g(None, s_in, 0.0, 0, dt)
    v_pre = s_in.v.numpy()
    np.testing.assert_allclose(v_pre[:, [0, 2]], np.broadcast_to([0.3, -0.2], (40, 2)), atol=ATOL)
    np.testing.assert_allclose(v_pre[:, 1], v_in[:, 1], atol=ATOL)
    g2p_x = x + 0.05
    g2p_v = np.ones((40, 3))
    s_out = state(g2p_x, v=g2p_v)
    prog.apply_post_g2p(None, s_in, s_out, 0.0, 0, dt)
    np.testing.assert_allclose(s_out.x.numpy()[:, 0], x[:, 0] + dt * 0.3, atol=ATOL)
    np.testing.assert_allclose(s_out.x.numpy()[:, 2], x[:, 2] - dt * 0.2, atol=ATOL)
    np.testing.assert_allclose(s_out.x.numpy()[:, 1], g2p_x[:, 1], atol=ATOL)
    np.testing.assert_allclose(
        s_out.v.numpy(), np.broadcast_to([0.3, 1.0, -0.2], (40, 3)), atol=ATOL
    )


def test_rotation_is_exact_rigid_rotation():
    c = np.array([0.05, -0.02, 0.2])
    x = c + np.random.default_rng(4).uniform(-0.1, 0.1, size=(60, 3))  # stays inside the clamp box
    axis = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
    omega, dt, steps = 3.0, 0.01, 50
    prog = program(
        forces=[
            {
                "type": "force_particles_rotation",
                "center": c.tolist(),
                "axis_direction": [0, 1, 1],
                "angular_velocity": omega,
            }
        ],
        x0=x,
    )
    s_in = state(x)
    for s in range(steps):
        s_out = state(s_in.x.numpy())  # a G2P that did nothing
        prog.apply_post_g2p(None, s_in, s_out, s * dt, s, dt)
        s_in = s_out
    theta = omega * dt * steps
    r = x - c
    k = axis
    expected = c + (
        r * np.cos(theta)
        + np.cross(k, r) * np.sin(theta)
        + np.outer(r @ k, k) * (1 - np.cos(theta))
    )
    # float32 accumulation over 50 steps of O(0.3) positions: a few 1e-7 per step.
    np.testing.assert_allclose(s_in.x.numpy(), expected, atol=2e-5)
    np.testing.assert_allclose(s_in.v.numpy(), omega * np.cross(k, expected - c), atol=2e-5)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    np.testing.assert_allclose(s_in.C.numpy(), np.broadcast_to(omega * skew, (60, 3, 3)), atol=ATOL)
    # pre-P2G sets the rigid velocity at the current position
    s_pre = state(x, v=np.ones((60, 3)))
    prog.apply_pre_p2g(None, s_pre, 0.0, 0, dt)
    np.testing.assert_allclose(s_pre.v.numpy(), omega * np.cross(k, x - c), atol=ATOL)


def test_release_particles_top_layer_first():
    # A column z in [0, 0.4]: 4 slabs of 0.1 released at t = 0.1 (top), 0.2, 0.3, 0.4 (bottom).
    # No particle sits near a slab boundary (0.1, 0.2, 0.3), so the layer of each is unambiguous.
    z = np.array([0.0] + [0.1 * g + 0.01 + 0.02 * j for g in range(4) for j in range(4)] + [0.4])
    x = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    prog = program(
        forces=[
            {
                "type": "release_particles",
                "layers": 4,
                "release_axis": "z",
                "start": 0.0,
                "end": 0.4,
            }
        ],
        x0=x,
    )
    layer_of = np.where(z >= 0.4, 0, 3 - np.floor(z / 0.1))  # 0 = top
    dt = 0.01
    for t in (0.0, 0.05, 0.15, 0.25, 0.35, 0.45):
        s_in = state(x, v=np.ones_like(x))
        prog.apply_pre_p2g(None, s_in, t, int(round(t / dt)), dt)
        s_out = state(
            x + np.array([0.01, 0.0, -0.01]), v=np.ones_like(x), C=np.ones((len(z), 3, 3))
        )
        prog.apply_post_g2p(None, s_in, s_out, t, int(round(t / dt)), dt)
        released = t >= 0.1 * (layer_of + 1)
        frozen = ~released
        np.testing.assert_array_equal(s_in.v.numpy()[frozen], 0.0)
        np.testing.assert_array_equal(s_in.v.numpy()[released], 1.0)
        np.testing.assert_allclose(s_out.x.numpy()[frozen], x[frozen], atol=ATOL)
        np.testing.assert_array_equal(s_out.C.numpy()[frozen], 0.0)
        np.testing.assert_allclose(
            s_out.x.numpy()[released], x[released] + [0.01, 0.0, -0.01], atol=ATOL
        )
        if 0.1 < t < 0.4:
            # the released set is a top slab: every released particle is above every frozen one
            assert released.any() and frozen.any()
            assert z[released].min() > z[frozen].max()


def test_empty_program_is_a_noop():
    prog = program()
    assert prog.is_empty and prog.params == []
    v = random_grid(seed=8)
    g = grid_array(v)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)
    np.testing.assert_array_equal(g.numpy(), v.astype(np.float32))


def test_region_launch_touches_only_the_region_and_matches_full_launch():
    bcs = [{"type": "surface_collider", "friction": 0.3}, {"type": "bounding_box", "friction": 0.2}]
    prog = program(bcs)
    v = random_grid(seed=9)
    full, part = grid_array(v), grid_array(v)
    prog.apply_grid(None, full, 0.0, 0, 1e-3)
    off, shape = (1, 2, 0), (5, 4, 6)
    prog.apply_grid(None, part, 0.0, 0, 1e-3, region=(off, shape))
    inside = np.zeros(DIMS, bool)
    inside[off[0] : off[0] + shape[0], off[1] : off[1] + shape[1], off[2] : off[2] + shape[2]] = (
        True
    )
    np.testing.assert_array_equal(part.numpy()[inside], full.numpy()[inside])
    np.testing.assert_array_equal(part.numpy()[~inside], v[~inside].astype(np.float32))
    assert not np.array_equal(full.numpy()[inside], v[inside].astype(np.float32))
    with pytest.raises(ValueError):
        prog.apply_grid(None, part, 0.0, 0, 1e-3, region=((5, 0, 0), (5, 1, 1)))


@pytest.mark.cuda
@pytest.mark.skipif(
    not wp.is_cuda_available(), reason="needs a CUDA device (Warp sees none on this machine)"
)
def test_cuda_matches_cpu():
    bcs = [
        {"type": "surface_collider", "friction": 0.3},
        {"type": "bounding_box", "friction": 0.2},
        {"type": "surface_collider", "mode": "cut", "box": [[0.1, -0.5, 0.0], [0.5, 0.5, 0.5]]},
    ]
    forces = [
        {"type": "add_constant_force", "force": [1, 0, -3]},
        {
            "type": "force_particles_rotation",
            "center": [0, 0, 0.2],
            "angular_velocity": 2.0,
            "sphere": [[0, 0, 0.2], 0.1],
        },
        {
            "type": "release_particles",
            "layers": 3,
            "end": 0.2,
            "box": [[-0.2, -0.2, 0.0], [0.0, 0.2, 0.4]],
        },
    ]
    x = particles(100)
    cfg = config_from_dict({"boundary_conditions": bcs, "forces": forces})
    v = random_grid(seed=10)
    out = {}
    for device in ("cpu", "cuda"):
        prog = BoundaryProgram.build(
            cfg.boundary_conditions,
            cfg.forces,
            x0=x,
            domain_lo=LO,
            dx=DX,
            grid_dims=DIMS,
            device=device,
        )
        g = wp.array(v.astype(np.float32), dtype=wp.vec3, device=device)
        prog.apply_grid(None, g, 0.05, 5, 0.01)
        with wp.ScopedDevice(device):
            s_in, s_out = state(x), state(x + 0.01, v=np.ones((100, 3)))
        prog.apply_pre_p2g(None, s_in, 0.05, 5, 0.01)
        prog.apply_post_g2p(None, s_in, s_out, 0.05, 5, 0.01)
        out[device] = [
            g.numpy(),
            s_in.v.numpy(),
            s_out.x.numpy(),
            s_out.v.numpy(),
            s_out.C.numpy(),
            s_out.active.numpy(),
        ]
    for a, b in zip(out["cpu"], out["cuda"], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)  # different FMA contraction / sin-cos only


def test_buffer_pool_reuses_and_stays_bounded():
    """The saved-source / scratch pool of recorded hooks hands back returned buffers of the
    same shape, and drops the least recently returned shapes past its byte cap (the active
    region's shape drifts as the material moves: an unbounded pool would leak)."""
    from motionphysics.sim.boundary import _BufferPool

    wp = init_warp()
    one = 10 * 10 * 10 * 12  # bytes of a (10, 10, 10) vec3 array
    pool = _BufferPool(cap=3 * one)
    a = pool.take((10, 10, 10), wp.vec3, "cpu")
    pool.give(a)
    assert pool.take((10, 10, 10), wp.vec3, "cpu") is a  # reused, not reallocated
    pool.give(a)
    for n in (11, 12, 13, 14, 15):
        pool.give(pool.take((n, 10, 10), wp.vec3, "cpu"))
        assert pool._bytes <= pool.cap
    # the oldest shapes went first; the newest is still there
    assert pool.take((10, 10, 10), wp.vec3, "cpu") is not a
    b = pool.take((15, 10, 10), wp.vec3, "cpu")
    assert b.shape == (15, 10, 10) and pool._bytes <= pool.cap


@pytest.mark.parametrize(
    "bc",
    [
        {"type": "bounding_box", "padding": 3, "friction": 0.3},
        {"type": "surface_collider", "point": [0, 0, 0.1], "normal": [0.3, 0.2, 1.0],
         "mode": "frictional", "friction": 0.5},
        {"type": "surface_collider", "point": [0, 0.1, 0], "normal": [0, -1, 0], "mode": "slip"},
        {"type": "surface_collider", "point": [0, 0, 0.0], "normal": [0, 0, 1], "mode": "sticky"},
    ],
)  # fmt: skip
def test_grid_ops_are_skipped_only_on_boxes_where_they_are_the_identity(bc):
    """``apply_grid`` skips an op on a region it cannot change (``_may_act`` False: walls
    out of reach, every node in front of a collider plane). On every sub-box of the grid,
    a skipped op's kernel (run on the full grid, in place) leaves the box's random
    velocities unchanged, and the skip happens on some boxes and not on others."""
    prog = program([bc])
    kind = bc["type"] if bc["type"] == "bounding_box" else bc["mode"]
    op = [o for o in prog._grid_ops if o.kind == kind][-1]
    prog._grid_ops = [op]  # this op alone (not the domain walls)
    v0 = random_grid(seed=3).astype(np.float32)
    g = grid_array(v0)
    prog.apply_grid(None, g, 0.0, 0, 1e-3)  # on the whole grid
    out = g.numpy()
    skipped = 0
    for off in [(a, b, c) for a in range(0, 8, 2) for b in range(0, 8, 3) for c in range(0, 8, 2)]:
        for size in (1, 2, 4):
            dims = tuple(min(size, n - o) for o, n in zip(off, DIMS, strict=True))
            if not prog._may_act(op, off, dims):
                skipped += 1
                box = tuple(slice(o, o + d) for o, d in zip(off, dims, strict=True))
                assert np.array_equal(out[box], v0[box]), (off, dims)
    assert 0 < skipped < 4 * 3 * 4 * 3


@pytest.mark.parametrize(
    "bc",
    [
        {"type": "bounding_box", "padding": 2, "friction": 0.3},
        {"type": "bounding_box", "padding": 4, "friction": 0.0},
        {"type": "surface_collider", "friction": 0.3},  # the ground: normal +z
        {"type": "surface_collider", "point": [0, 0.1, 0], "normal": [0, -1, 0], "mode": "slip"},
        {"type": "surface_collider", "point": [0.13, 0, 0], "normal": [1, 0, 0], "mode": "sticky"},
        {"type": "surface_collider", "normal": [0.2, 0.1, 1.0], "friction": 0.4},  # tilted
    ],
)  # fmt: skip
def test_grid_ops_launch_on_disjoint_pieces_that_give_the_whole_box_launch(bc):
    """``apply_grid`` launches a wall or an axis-aligned plane only on the nodes it may
    change (``_act_boxes``: wall slabs, the nodes behind a plane). On every sub-box of the
    grid the pieces are disjoint, lie in the box, and the result is bitwise the result of
    the op's kernel launched on the whole box; the pieces are smaller than the box where
    the op reaches only part of it."""
    from motionphysics.sim import boundary_kernels as K

    prog = program([bc])
    kind = bc["type"] if bc["type"] == "bounding_box" else bc.get("mode", "frictional")
    op = [o for o in prog._grid_ops if o.kind == kind][-1]
    prog._grid_ops = [op]  # this op alone (not the domain walls)
    v0 = random_grid(seed=5).astype(np.float32)
    whole = grid_array(v0)
    prog._launch_grid_op(K, op, whole, (0, 0, 0), DIMS, prog.domain_lo, prog.dx)
    out = whole.numpy()
    smaller = 0
    for off in [(a, b, c) for a in range(0, 9, 2) for b in range(0, 9, 3) for c in range(0, 9, 2)]:
        for size in (1, 3, 5, 9):
            dims = tuple(min(size, n - o) for o, n in zip(off, DIMS, strict=True))
            cover = np.zeros(DIMS, int)
            pieces = prog._act_boxes(op, off, dims)
            for p_off, p_dims in pieces:
                assert all(
                    o <= po and po + pd <= o + d and pd > 0
                    for o, d, po, pd in zip(off, dims, p_off, p_dims, strict=True)
                ), (off, dims, pieces)
                cover[tuple(slice(o, o + d) for o, d in zip(p_off, p_dims, strict=True))] += 1
            assert cover.max(initial=0) <= 1, (off, dims, pieces)  # disjoint
            smaller += int(0 < cover.sum() < np.prod(dims))
            g = grid_array(v0)
            prog.apply_grid(None, g, 0.0, 0, 1e-3, region=(off, dims))
            box = tuple(slice(o, o + d) for o, d in zip(off, dims, strict=True))
            inside = np.zeros(DIMS, bool)
            inside[box] = True
            np.testing.assert_array_equal(g.numpy()[inside], out[inside])
            np.testing.assert_array_equal(g.numpy()[~inside], v0[~inside])
    if "normal" not in bc or bc["normal"] in ([0, -1, 0], [1, 0, 0]):
        assert smaller > 0  # the walls and axis-aligned planes launch on less than the box
