"""Camera conventions against hand-computed projections (OpenCV axes, z-up world)."""

import json
import math

import pytest
import torch

from motionphysics.config import CameraConfig
from motionphysics.errors import UserInputError
from motionphysics.render.camera import (
    camera_from_config,
    frame_bounds,
    load_inria_cameras,
    orbit_camera,
)


def test_known_point_lands_on_analytic_pixel():
    # Camera on +x at 5 m looking at the origin: right = +y, down = -z, forward = -x.
    cam = orbit_camera(0.0, 0.0, 5.0, (0, 0, 0), fov=60.0, width=200, height=100)
    f = 50.0 / math.tan(math.radians(30.0))
    assert cam.fx == pytest.approx(f) and cam.fy == pytest.approx(f)
    uv, z = cam.project(torch.tensor([[0.0, 1.0, 0.5]], dtype=torch.float64))
    assert z.item() == pytest.approx(5.0)
    assert uv[0, 0].item() == pytest.approx(100.0 + f * 1.0 / 5.0)
    assert uv[0, 1].item() == pytest.approx(50.0 - f * 0.5 / 5.0)
    assert torch.allclose(cam.position, torch.tensor([5.0, 0.0, 0.0], dtype=torch.float64))


@pytest.mark.parametrize("az,el", [(0, 0), (30, 20), (135, -40), (-80, 89), (200, 90), (10, -90)])
def test_orbit_looks_at_target_and_up_is_up(az, el):
    target = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)
    cam = orbit_camera(az, el, 2.5, target.tolist(), 45.0, 64, 48)
    R = cam.rotation
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.det(R).item() == pytest.approx(1.0)
    assert (cam.position - target).norm().item() == pytest.approx(2.5)
    uv, z = cam.project(target[None])
    assert torch.allclose(uv[0], torch.tensor([32.0, 24.0], dtype=torch.float64), atol=1e-9)
    assert z.item() == pytest.approx(2.5)
    # Azimuth counter-clockwise from +x about z, elevation above the horizon.
    a, e = math.radians(az), math.radians(el)
    expect = target + 2.5 * torch.tensor(
        [math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)], dtype=torch.float64
    )
    assert torch.allclose(cam.position, expect, atol=1e-12)
    if abs(el) < 89:
        up_pt = target + torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64)
        uv_up, _ = cam.project(up_pt[None])
        assert uv_up[0, 1] < 24.0  # higher in the image (rows grow downwards)
        assert uv_up[0, 0].item() == pytest.approx(32.0, abs=1e-9)  # no roll


def test_azimuth_90_puts_camera_on_plus_y():
    cam = orbit_camera(90.0, 0.0, 3.0)
    assert torch.allclose(
        cam.position, torch.tensor([0.0, 3.0, 0.0], dtype=torch.float64), atol=1e-12
    )


def test_inria_cameras_json(tmp_path):
    # c2w columns: camera x = world +y, camera y = world -z, camera z = world -x (looks at origin).
    c2w = [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    entry = {
        "id": 0,
        "img_name": "a",
        "width": 80,
        "height": 60,
        "position": [4.0, 0.0, 0.0],
        "rotation": c2w,
        "fx": 70.0,
        "fy": 71.0,
    }
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([entry]))
    (cam,) = load_inria_cameras(path)
    ref = orbit_camera(0.0, 0.0, 4.0)
    assert torch.allclose(cam.world_to_cam, ref.world_to_cam, atol=1e-12)
    uv, _ = cam.project(torch.tensor([[0.0, 0.4, 0.2]], dtype=torch.float64))
    assert uv[0].tolist() == pytest.approx([40.0 + 70.0 * 0.1, 30.0 - 71.0 * 0.05])
    cfg = CameraConfig(cameras_json=str(path), camera_index=0, width=160, height=120)
    big = camera_from_config(cfg)
    assert (big.width, big.height, big.fx) == (160, 120, 140.0)
    with pytest.raises(UserInputError, match="camera_index"):
        camera_from_config(CameraConfig(cameras_json=str(path), camera_index=3))


@pytest.mark.parametrize(
    "text,match",
    [("not json", "not valid JSON"), ("[]", "non-empty"), ('[{"width": 3}]', "expected fields")],
)
def test_inria_cameras_bad_input(tmp_path, text, match):
    path = tmp_path / "cameras.json"
    path.write_text(text)
    with pytest.raises(UserInputError, match=match):
        load_inria_cameras(path)


def test_camera_from_config_default_matches_orbit():
    cfg = CameraConfig()
    cam = camera_from_config(cfg)
    ref = orbit_camera(
        cfg.azimuth, cfg.elevation, cfg.radius, cfg.look_at, cfg.fov, cfg.width, cfg.height
    )
    assert torch.equal(cam.world_to_cam, ref.world_to_cam)


def test_frame_bounds_sees_whole_box():
    lo, hi = (-1.0, -0.5, 0.0), (1.0, 0.5, 2.0)
    cam = frame_bounds(lo, hi, 30.0, 20.0, 45.0, 128, 96)
    corners = torch.tensor(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
        dtype=torch.float64,
    )
    uv, z = cam.project(corners)
    assert (z > 0).all()
    assert (uv[:, 0] > 0).all() and (uv[:, 0] < 128).all()
    assert (uv[:, 1] > 0).all() and (uv[:, 1] < 96).all()


def test_orbit_bad_input():
    with pytest.raises(UserInputError, match="radius"):
        orbit_camera(0, 0, -1.0)
    with pytest.raises(UserInputError, match="fov"):
        orbit_camera(0, 0, 1.0, fov=180.0)


def _sideways_trajectory(frames: int = 10, n: int = 2000, seed: int = 0):
    """A 0.2 m ball sliding 2 m along +x over ``frames`` frames, [T, n, 3] float32."""
    import numpy as np

    rng = np.random.default_rng(seed)
    ball = rng.normal(size=(n, 3))
    ball = 0.1 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    shift = np.linspace(0.0, 2.0, frames)[:, None, None] * np.array([1.0, 0.0, 0.0])
    return (ball[None] + shift + np.array([0.0, 0.0, 0.1])).astype(np.float32)


def test_trajectory_bounds_is_union_of_frames_and_ignores_strays():
    import numpy as np

    from motionphysics.render.camera import trajectory_bounds

    xs = _sideways_trajectory()
    lo, hi = trajectory_bounds(xs, 0.0, 100.0)
    np.testing.assert_allclose(lo, xs.reshape(-1, 3).min(0), atol=1e-6)
    np.testing.assert_allclose(hi, xs.reshape(-1, 3).max(0), atol=1e-6)
    # One stray point 50 m away in one frame (0.05 % of the points) does not move the box.
    xs2 = xs.copy()
    xs2[3, 0] = (50.0, 50.0, 50.0)
    lo2, hi2 = trajectory_bounds(xs2)
    assert max(hi2) < 2.2 and min(lo2) > -0.2
    # Torch input and a single frame work too.
    lo3, hi3 = trajectory_bounds(torch.from_numpy(xs[0]), 0.0, 100.0)
    np.testing.assert_allclose(hi3, xs[0].max(0), atol=1e-6)
    with pytest.raises(ValueError):
        trajectory_bounds(np.zeros((3, 0, 3)))


def test_frame_trajectory_keeps_a_moving_object_in_view():
    import numpy as np

    from motionphysics.render.camera import frame_trajectory

    xs = _sideways_trajectory()
    W, H = 128, 96

    def inside(cam, pts) -> float:
        uv, z = cam.project(torch.from_numpy(pts.astype(np.float64)))
        ok = (z[:, 0] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        return float(ok.double().mean())

    cam = frame_trajectory(xs, 30.0, 20.0, 45.0, W, H)
    assert all(inside(cam, xs[t]) == 1.0 for t in range(len(xs)))
    # Framing only the first frame (what the automatic camera did) loses the last frame.
    first = frame_bounds(xs[0].min(0).tolist(), xs[0].max(0).tolist(), 30.0, 20.0, 45.0, W, H)
    assert inside(first, xs[0]) == 1.0 and inside(first, xs[-1]) < 0.5
