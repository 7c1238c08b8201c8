"""scene.region, scene.up and the static collider (issue 25), on builtin scenes: the
splats outside the region are kept exactly as transformed, the static scene becomes a
level set that holds a body up, the up axis turns a capture's vertical to +z, and the
capture's cameras follow the scene transform."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from motionphysics.config import RunConfig, load_config
from motionphysics.errors import UserInputError
from motionphysics.scene import load_scene
from motionphysics.scene.gaussians import GaussianScene
from motionphysics.scene.prepare import prepare, transform_scene
from motionphysics.scene.region import region_mask, up_rotation


def _slab_and_ball() -> GaussianScene:
    """A 0.6 m square slab of flat splats (the table) at z = 0 and a sphere on it."""
    ball, _ = transform_scene(load_scene("builtin:sphere"), 0.1, [], (0.0, 0.0, 0.105))
    g = np.linspace(-0.3, 0.3, 61)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    n = xx.size
    means = torch.tensor(np.stack([xx.ravel(), yy.ravel(), np.zeros(n)], 1), dtype=torch.float32)
    k = ball.sh.shape[1]
    sh = torch.zeros((n, k, 3))
    sh[:, 0, :] = 0.5
    slab = GaussianScene(
        means=means,
        log_scales=torch.log(torch.tensor([[0.008, 0.008, 0.001]]).expand(n, 3).clone()),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(n, 4).clone(),
        logit_opacities=torch.full((n,), 4.0),
        sh=sh,
    )
    return GaussianScene.concat([ball, slab])


def _cfg(**scene) -> RunConfig:
    return RunConfig.model_validate(
        {
            "scene": {"source": "x.ply", "max_particles": 2000, **scene},
            "sim": {"grid": 24, "frames": 4},
            "boundary_conditions": [],
        }
    )


def test_up_rotation_turns_the_named_axis_to_z():
    for up, v in (("y", (0, 1, 0)), ("-y", (0, -1, 0)), ("x", (1, 0, 0)), ("-z", (0, 0, -1))):
        r = up_rotation(up)
        assert np.allclose(r @ np.array(v, float), [0, 0, 1], atol=1e-15)
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    assert np.array_equal(up_rotation("z"), np.eye(3))
    u = np.array([0.03, -0.75, -0.66])
    assert np.allclose(up_rotation(list(u)) @ (u / np.linalg.norm(u)), [0, 0, 1])


def test_region_keeps_the_rest_of_the_scene_unchanged_and_colliding():
    scene = _slab_and_ball()
    scene.means[scene.means[:, 2] == 0, 2] = -0.0  # signed zeros keep their sign too
    cfg = _cfg(region={"sphere": [[0.0, 0.0, 0.105], 0.12]})
    ss = prepare(scene, cfg.scene, cfg.sim, [], [])
    inside = region_mask(scene.means.double().numpy(), cfg.scene.region)
    assert ss.splats.num == int(inside.sum()) and ss.static_splats.num == int((~inside).sum())
    # the static splats exactly as given (identity transform: the input's bits)
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
        got = getattr(ss.static_splats, name)
        want = getattr(scene, name)[~torch.from_numpy(inside)]
        assert torch.equal(got.view(torch.int32), want.view(torch.int32)), name
    col = ss.static_collider
    assert col is not None and col.mode == "frictional" and col.friction == pytest.approx(0.3)
    assert col.h == pytest.approx(ss.dx / 4)
    # the slab's top is the level set's zero, within a cell; inside negative, above positive
    probe = np.array([[0.15, 0.0, 0.0], [0.15, 0.0, ss.dx], [0.15, 0.0, -0.25 * col.h]])
    phi = col.sample(probe)
    assert phi[0] <= 0 < phi[1] and phi[2] < 0
    assert ss.static_note is None  # a full slab holds the ball


def test_crop_discards_what_region_keeps():
    scene = _slab_and_ball()
    cropped = _cfg(crop=[-0.12, 0.12, -0.12, 0.12, 0.0, 0.3])
    ss = prepare(scene, cropped.scene, cropped.sim, [], [])
    assert ss.static_splats is None and ss.static_collider is None


def test_a_region_over_thin_air_says_the_static_scene_is_too_sparse():
    ball, _ = transform_scene(load_scene("builtin:sphere"), 0.1, [], (0.0, 0.0, 0.5))
    wall, _ = transform_scene(load_scene("builtin:cube"), 0.1, [], (0.6, 0.0, 0.5))
    cfg = _cfg(region={"box": [[-0.2, -0.2, 0.3], [0.2, 0.2, 0.7]]})
    ss = prepare(GaussianScene.concat([ball, wall]), cfg.scene, cfg.sim, [], [])
    assert ss.static_note is not None and ss.static_note.startswith("static scene: only ")
    assert "may fall through" in ss.static_note and "\n" not in ss.static_note


def test_region_errors_are_one_line(tmp_path):
    scene = _slab_and_ball()
    cfg = _cfg(region={"box": [[2.0, 2.0, 2.0], [3.0, 3.0, 3.0]]})
    with pytest.raises(UserInputError, match=r"scene.region \{box: .* holds none of the"):
        prepare(scene, cfg.scene, cfg.sim, [], [])
    bad = tmp_path / "bad.yaml"
    bad.write_text("scene: {region: {box: [[1, 0, 0], [0, 1, 1]]}}\n")
    with pytest.raises(UserInputError, match="min < max"):
        load_config(bad)
    bad.write_text("scene: {static_collider: sticky}\n")
    with pytest.raises(UserInputError, match="only with scene.region"):
        load_config(bad)
    bad.write_text("scene: {up: [0, 0, 0]}\n")
    with pytest.raises(UserInputError, match="non-zero"):
        load_config(bad)


def test_static_collider_holds_a_ball_on_a_table_of_splats(tmp_path):
    """The static slab holds the simulated ball with no collider plane in the config."""
    from motionphysics.scene.ply import write_ply

    src = tmp_path / "table.ply"
    write_ply(_slab_and_ball(), src)
    cfg = RunConfig.model_validate(
        {
            "scene": {
                "source": str(src),
                "region": {"sphere": [[0.0, 0.0, 0.105], 0.12]},
                "max_particles": 1500,
            },
            "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
            "sim": {"grid": 20, "frames": 8, "frame_dt": 0.04, "substeps": 40},
            "camera": {"width": 16, "height": 16},
        }
    )
    from motionphysics.assembly import assemble

    parts = assemble(cfg, reference_image=False)
    assert parts.cfg.boundary_conditions == []  # no floor: the static scene holds it
    assert parts.scene_notes["ground"].startswith("ground: the static scene")
    xs, _Fs, _vs, _n = parts.simulate()
    lowest = xs[:, :, 2].min(axis=1)
    assert lowest.min() > -0.1 * parts.sim_scene.dx  # never through the table
    assert lowest[-1] < 2.0 * parts.sim_scene.dx


def test_capture_cameras_follow_the_scene_transform(tmp_path):
    """A nerfstudio transforms.json and the same view as INRIA cameras.json give one camera;
    moved by the scene transform, a point keeps its pixel."""
    from motionphysics.render.camera import load_capture_cameras, transform_camera

    c2w_cv = np.eye(3)[:, [0, 1, 2]] @ np.diag([1.0, 1.0, 1.0])
    rot = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # a camera looking along +y
    pos = np.array([0.1, -2.0, 0.3])
    del c2w_cv
    (tmp_path / "cameras.json").write_text(
        json.dumps(
            [
                {
                    "id": 0,
                    "img_name": "a",
                    "width": 64,
                    "height": 48,
                    "position": pos.tolist(),
                    "rotation": rot.tolist(),
                    "fx": 50.0,
                    "fy": 50.0,
                }
            ]
        )
    )
    gl = rot @ np.diag([1.0, -1.0, -1.0])  # OpenGL axes of the same camera
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = gl, pos
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {
                "w": 64,
                "h": 48,
                "fl_x": 50.0,
                "fl_y": 50.0,
                "frames": [{"transform_matrix": m.tolist()}],
            }
        )
    )
    a = load_capture_cameras(tmp_path / "cameras.json")[0]
    b = load_capture_cameras(tmp_path / "transforms.json")[0]
    assert torch.allclose(a.world_to_cam, b.world_to_cam, atol=1e-12)
    p = torch.tensor([[0.3, 1.0, 0.2]], dtype=torch.float64)
    uv, z = a.project(p)
    assert z.item() > 0
    s2w = np.eye(4)
    s2w[:3, :3] = 0.04 * up_rotation("y")
    s2w[:3, 3] = [0.5, -0.2, 0.1]
    moved = transform_camera(a, torch.from_numpy(s2w))
    pw = torch.from_numpy((s2w[:3, :3] @ p.numpy()[0] + s2w[:3, 3])[None])
    uv2, _ = moved.project(pw)
    assert torch.allclose(uv, uv2, atol=1e-9)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(UserInputError, match="not a camera file"):
        load_capture_cameras(tmp_path / "bad.json")


def test_gradient_through_the_static_collider_matches_finite_differences(tmp_path):
    """A ball sliding on the static slab: d(mean x at the last frame)/d(static friction)
    through the bridge (the level-set kernels' recorded adjoints) against central
    differences (measured: -0.03613 vs -0.03608)."""
    from motionphysics.assembly import assemble
    from motionphysics.scene.ply import write_ply
    from motionphysics.sim.bridge import simulate

    src = tmp_path / "table.ply"
    write_ply(_slab_and_ball(), src)
    cfg = RunConfig.model_validate(
        {
            "scene": {
                "source": str(src),
                "region": {"sphere": [[0.0, 0.0, 0.105], 0.12]},
                "max_particles": 800,
            },
            "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
            "sim": {
                "grid": 16,
                "frames": 6,
                "frame_dt": 0.02,
                "substeps": 30,
                "initial_velocity": [0.8, 0.0, -0.3],
            },
            "camera": {"width": 16, "height": 16},
        }
    )
    sim = assemble(cfg, needs_grad=True, reference_image=False).simulation
    assert sim.model.boundary.has_static

    def mean_x(mu: float, grad: bool = False):
        f = torch.tensor(mu, requires_grad=grad)
        xs, _ = simulate(sim, {}, frames=[5], forces={"scene.static_friction": f})
        loss = xs[-1][:, 0].mean()
        if grad:
            loss.backward()
            return f.grad.item()
        return loss.item()

    g = mean_x(0.3, grad=True)
    fd = (mean_x(0.35) - mean_x(0.25)) / 0.1
    assert g < 0  # more friction, less sliding
    assert g == pytest.approx(fd, rel=0.05)


def test_objects_cut_from_one_capture_share_its_static_scene(tmp_path):
    """Two objects: entries with a region each; the static scene is the capture outside
    both regions, drawn once."""
    from motionphysics.scene.ply import write_ply
    from motionphysics.scene.prepare import prepare_objects

    a, _ = transform_scene(load_scene("builtin:sphere"), 0.1, [], (-0.15, 0.0, 0.105))
    b, _ = transform_scene(load_scene("builtin:sphere"), 0.1, [], (0.15, 0.0, 0.105))
    slab = _slab_and_ball()
    scene = GaussianScene.concat([a, b, slab])
    src = tmp_path / "two.ply"
    write_ply(scene, src)
    cfg = RunConfig.model_validate(
        {
            "objects": [
                {
                    "name": "left",
                    "source": str(src),
                    "max_particles": 800,
                    "region": {"sphere": [[-0.15, 0.0, 0.105], 0.11]},
                },
                {
                    "name": "right",
                    "source": str(src),
                    "max_particles": 800,
                    "region": {"sphere": [[0.15, 0.0, 0.105], 0.11]},
                },
            ],
            "sim": {"grid": 20, "frames": 4},
            "boundary_conditions": [],
        }
    )
    loaded = load_scene(str(src))
    ss = prepare_objects([loaded, loaded], cfg.objects, cfg.sim, [], [])
    p = loaded.means.double().numpy()
    inside = region_mask(p, cfg.objects[0].region) | region_mask(p, cfg.objects[1].region)
    assert ss.static_splats.num == int((~inside).sum())
    assert ss.splats.num == int(inside.sum())
    assert ss.static_collider is not None
    assert set(np.unique(ss.object_id.numpy())) == {0, 1}


def test_particles_starting_inside_the_static_scene_are_said():
    """A region whose particles start deep inside static splats gets one line saying the
    first substep pushes them out (here: particles placed inside a thick static block)."""
    from motionphysics.scene.prepare import _static_parts

    g = np.linspace(-0.2, 0.2, 41)  # 1 cm apart: the splats' one-sigma boxes touch
    pts = np.stack(np.meshgrid(g, g, g - 0.2, indexing="ij"), -1).reshape(-1, 3)
    n = len(pts)
    block = GaussianScene(  # a solid block of splats (a hollow shell would hold it inside)
        means=torch.tensor(pts, dtype=torch.float32),
        log_scales=torch.full((n, 3), float(np.log(0.01))),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(n, 4).clone(),
        logit_opacities=torch.full((n,), 4.0),
        sh=torch.full((n, 1, 3), 0.5),
    )
    cfg = _cfg(region={"box": [[-0.1, -0.1, 0.0], [0.1, 0.1, 0.2]]})
    dx = 0.02
    lo = np.array([-0.3, -0.3, -0.45])
    g = np.linspace(-0.05, 0.05, 6)
    inside = np.stack(np.meshgrid(g, g, g - 0.2, indexing="ij"), -1).reshape(-1, 3)
    _col, note = _static_parts(block, [cfg.scene], lo, dx, (31, 31, 36), inside, cfg.sim)
    assert note is not None and "start more than a cell inside the static splats" in note
    assert "\n" not in note


def test_static_collider_modes_hold_a_sliding_ball_differently(tmp_path):
    """A ball thrown sideways onto the slab: sticky stops it, slip lets it run further
    than frictional; none lets it through the table."""
    from motionphysics.assembly import assemble
    from motionphysics.scene.ply import write_ply

    src = tmp_path / "table.ply"
    write_ply(_slab_and_ball(), src)
    runs = {}
    for mode in ("sticky", "frictional", "slip"):
        cfg = RunConfig.model_validate(
            {
                "scene": {
                    "source": str(src),
                    "region": {"sphere": [[0.0, 0.0, 0.105], 0.12]},
                    "max_particles": 600,
                    "static_collider": mode,
                    **({"static_friction": 0.5} if mode == "frictional" else {}),
                },
                "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
                "sim": {
                    "grid": 16,
                    "frames": 6,
                    "frame_dt": 0.02,
                    "substeps": 30,
                    "initial_velocity": [0.8, 0.0, -0.3],
                },
                "camera": {"width": 16, "height": 16},
            }
        )
        parts = assemble(cfg, reference_image=False)
        xs, _Fs, _vs, _n = parts.simulate()
        assert xs[:, :, 2].min() > -0.1 * parts.sim_scene.dx, mode
        runs[mode] = float(xs[-1][:, 0].mean() - xs[0][:, 0].mean())
    assert runs["sticky"] < runs["frictional"] < runs["slip"], runs


def test_a_capture_camera_file_frames_the_scene_after_its_transform(tmp_path):
    """camera.from: a nerfstudio transforms.json whose camera looks at the ball in the
    capture's frame still sees it at the image centre once the scene is scaled, turned
    (up: y) and moved: the camera follows the transform."""
    from motionphysics.assembly import assemble
    from motionphysics.scene.ply import write_ply

    # the capture, y-up: the ball at (0, 0.105, 0) of the capture's frame
    scene = _slab_and_ball()
    r = torch.from_numpy(up_rotation("y").T).float()  # z-up -> the capture's y-up
    scene.means = scene.means @ r.T
    src = tmp_path / "capture.ply"
    write_ply(scene, src)
    # a camera 1 m in front of the ball (capture +z), looking at it: OpenGL axes
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.105, 1.0]
    (tmp_path / "transforms.json").write_text(
        json.dumps({"w": 40, "h": 40, "fl_x": 60.0, "frames": [{"transform_matrix": c2w.tolist()}]})
    )
    cfg = RunConfig.model_validate(
        {
            "scene": {
                "source": str(src),
                "up": "y",
                "scale": 2.0,
                "translate": [0.3, -0.2, 0.1],
                "region": {"sphere": [[0.3, -0.2, 0.1 + 0.21], 0.24]},
                "max_particles": 600,
            },
            "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
            "sim": {"grid": 16, "frames": 2},
            "camera": {"from": str(tmp_path / "transforms.json"), "width": 40, "height": 40},
        }
    )
    parts = assemble(cfg)
    assert parts.camera_note == {"framing": "config"}
    img = parts.reference_image
    centre = img[18:22, 18:22].reshape(-1, 3).astype(int)
    assert (centre.sum(axis=1) < 3 * 240).all()  # the ball, not the white background
    corner = img[:3, :3].reshape(-1, 3).astype(int)
    assert (corner.sum(axis=1) > 3 * 240).all()  # nothing there: the camera sees the ball only
