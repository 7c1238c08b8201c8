"""Issue 25 on the shared real capture, through ``motionphysics run CONFIG``: a region of
``yashica_t4_table.ply`` (the camera body) is simulated, the rest of the capture (the
table, the strap, the room) stays.

Judged as a person would judge the run directory: every static splat of every frame of
``splats/`` is bit-identical to the input (the capture under the config's transform, as
``scene.ply`` holds it with ``simulated = 0``), the camera has moved, it rests on the
table (its lowest point within 2 grid cells of the table's top and never more than 0.1
cell below it), and the video shows the table. The capture's vertical axis is the
normal of the plane its strap lies on (the "y" of Brush's header is the capture's y,
tilted 41 degrees from the table's normal), so ``scene.up`` is that vector.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from motionphysics.cli import main

CAPTURE = (
    Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "yashica_t4_table.ply"
)
pytestmark = pytest.mark.skipif(
    not CAPTURE.is_file(), reason="real capture shared/data/real/yashica_t4_table.ply not present"
)

UP = [0.03413075, -0.75571442, -0.65401132]
"""The table's normal in the capture's frame (the plane the strap lies on, fitted)."""
SCENE = {
    "source": str(CAPTURE),
    "up": UP,
    "scale": 0.04,  # capture units -> m (the camera body is ~12 cm wide)
    "translate": [0.0172, -0.0344, 0.1491],  # the table's top at z ~ 0, the camera near x = y = 0
    "region": {"box": [[-0.062, -0.031, 0.0012], [0.062, 0.031, 0.07]]},  # the camera body
    "max_particles": 3000,
}
CONFIG = {
    "scene": SCENE,
    "prompt": "A plastic camera is tossed up and lands back on the wooden table.",
    "material": {"class": "elastic", "density": 800.0, "E": 2.0e5, "nu": 0.3},
    "sim": {"grid": 32, "frames": 12, "frame_dt": 0.04, "initial_velocity": [0.0, 0.0, 0.3]},
    "camera": {"width": 96, "height": 96, "elevation": 30},
    "export_ply": True,
}


PUSH = {
    **CONFIG,
    "prompt": "A plastic camera is pushed across the wooden table and stops.",
    # stiffer than the toss's: the capture is a shell (no interior fill at this grid), and
    # a soft shell pushed sideways folds over the table's edge behind it
    "material": {"class": "elastic", "density": 800.0, "E": 2.0e6, "nu": 0.3},
    "sim": {"grid": 32, "frames": 14, "frame_dt": 0.04},
    "forces": [{"type": "add_impulse", "force": [0.25, 0.0, 0.15], "start": 0.0}],
}
"""A push: the camera hops sideways off the place it stood and slides to a stop on the
sparse part of the table (the gaps between its splats closed, scene.region)."""


@pytest.fixture(scope="module", params=["toss", "push"])
def run_dir(tmp_path_factory, request):
    root = tmp_path_factory.mktemp(f"region_capture_{request.param}")
    cfg = root / "camera_on_table.yaml"
    data = CONFIG if request.param == "toss" else PUSH
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    out = root / "run"
    assert main(["run", str(cfg), "--out", str(out), "--quiet"]) == 0
    return out


def _static_and_sim(path):
    from motionphysics.scene.ply import read_ply, read_ply_property

    splats = read_ply(path)
    flag = read_ply_property(path, "simulated")
    assert flag is not None, f"{path}: no per-splat simulated flag"
    return splats, np.asarray(flag) != 0


def _bits(a):
    return np.ascontiguousarray(a.numpy()).view(np.uint32)


def test_static_splats_are_bit_identical_to_the_input_in_every_frame(run_dir):
    from motionphysics.config import SceneConfig
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import transform_scene
    from motionphysics.scene.region import region_mask

    sc = SceneConfig(**SCENE)
    placed, _ = transform_scene(load_scene(str(CAPTURE)), sc.scale, sc.rotate, sc.translate, sc.up)
    outside = ~region_mask(placed.means.double().numpy(), sc.region)
    expected = placed.subset(np.nonzero(outside)[0])
    scene, sim = _static_and_sim(run_dir / "scene.ply")
    assert (~sim).sum() == expected.num > 4000  # the table, the strap, the room
    frames = sorted((run_dir / "splats").glob("frame_*.ply"))
    assert len(frames) == np.load(run_dir / "trajectory.npz")["x"].shape[0] >= 12
    for f in [run_dir / "scene.ply", *frames]:
        splats, sim_f = _static_and_sim(f)
        assert np.array_equal(sim_f, sim)
        for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
            got = getattr(splats, name)[torch_index(~sim_f)]
            assert np.array_equal(_bits(got), _bits(getattr(expected, name))), (f.name, name)


def torch_index(mask):
    import torch

    return torch.from_numpy(np.nonzero(mask)[0])


def _table_top(run_dir):
    """Median height [m] of the static splat centres around the camera's footprint (5 to
    30 mm from it across, within 1 cm of its initial bottom): the table's top."""
    from scipy.spatial import cKDTree

    scene, sim = _static_and_sim(run_dir / "scene.ply")
    static = scene.means[torch_index(~sim)].double().numpy()
    traj = np.load(run_dir / "trajectory.npz")
    x0 = traj["x"][0].astype(np.float64)
    d, _ = cKDTree(x0[:, :2]).query(static[:, :2])
    ring = (d > 0.005) & (d < 0.03) & (np.abs(static[:, 2] - x0[:, 2].min()) < 0.01)
    assert ring.sum() > 500
    return float(np.median(static[ring, 2])), traj


def test_the_camera_moves_and_comes_to_rest_on_the_table(run_dir):
    top, traj = _table_top(run_dir)
    x = traj["x"].astype(np.float64)
    dx = float(traj["dx"])
    lowest = x[:, :, 2].min(axis=1)  # [T] the camera's lowest particle
    # it moved: it does not end where it started
    assert np.abs(x[-1] - x[0]).max() > 0.1 * dx
    assert np.abs(x - x[0]).max() > 0.3 * dx
    # it rests on the table: within 2 cells above its top, never more than 0.1 cell below
    assert top - 0.1 * dx <= lowest[-1] <= top + 2.0 * dx, ((lowest - top) / dx).round(2)
    assert (lowest >= top - 0.1 * dx).all(), ((lowest - top) / dx).round(2)
    # and at rest: the last frames move by less than a tenth of a cell per frame
    assert np.abs(x[-1] - x[-2]).max() < 0.1 * dx


def test_the_video_shows_the_table(run_dir):
    import imageio.v3 as iio

    from motionphysics.config import load_config
    from motionphysics.render.camera import camera_from_config

    video = iio.imread(run_dir / "video.mp4")
    cfg = load_config(run_dir / "run.yaml")
    cam = camera_from_config(cfg.camera)
    top, traj = _table_top(run_dir)
    scene, sim = _static_and_sim(run_dir / "scene.ply")
    static = scene.means[torch_index(~sim)].double()
    near = (static[:, 2] - top).abs() < 0.005
    uv, z = cam.project(static[near])
    inside = (z[:, 0] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width)
    inside &= (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    assert int(inside.sum()) > 200  # the table lies in the picture...
    px = uv[inside].long().numpy()
    last = video[-1].astype(np.int64)
    shade = last[px[:, 1], px[:, 0]].sum(axis=1)
    # ... and is drawn there (not the white background) in the last frame
    assert (shade < 3 * 235).mean() > 0.8


def test_the_viewer_draws_the_static_scene_in_every_frame(run_dir):
    from motionphysics.render.camera import orbit_camera
    from motionphysics.viewer.frames import FrameSource
    from motionphysics.viewer.rundata import load_run

    run = load_run(run_dir)
    scene, sim = _static_and_sim(run_dir / "scene.ply")
    assert run.splats.num == int(sim.sum()) == run.parent.shape[0]
    assert run.static is not None and run.static.num == int((~sim).sum())
    src = FrameSource(run, orbit_camera(30, 20, 0.4, (0, 0, 0.03)), max_splats=None)
    for k in (0, run.num_frames - 1):
        frame = src.frame(k)
        assert frame.means.shape[0] == scene.num
        static_means = scene.means[torch_index(~sim)].numpy()
        assert np.array_equal(frame.means[int(sim.sum()) :], static_means)


def test_a_tilted_up_axis_is_said_with_the_vector_that_levels_the_table():
    """``up: y`` (the axis Brush's header names) leaves this capture's table 138 degrees
    from level; the run says so and names the up vector that levels it (the table's
    normal, within 5 degrees of the one fitted for this test)."""
    import re

    from motionphysics.config import RunConfig
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare, transform_scene

    scene = load_scene(str(CAPTURE))
    placed, _ = transform_scene(scene, 0.04, [], (0.0, 0.0, 0.0), "y")
    m = placed.means.numpy()
    box = [np.percentile(m, 30, axis=0).tolist(), np.percentile(m, 70, axis=0).tolist()]
    cfg = RunConfig.model_validate(
        {
            "scene": {"source": str(CAPTURE), "up": "y", "scale": 0.04, "region": {"box": box}},
            "sim": {"grid": 24, "frames": 4},
        }
    )
    note = prepare(scene, cfg.scene, cfg.sim, [], []).static_note
    got = re.search(r"scene\.up: \[([-0-9., ]+)\]", note or "")
    assert got, note
    u = np.array([float(v) for v in got.group(1).split(",")])
    cos = float(u @ np.array(UP)) / np.linalg.norm(u) / np.linalg.norm(UP)
    assert np.degrees(np.arccos(min(cos, 1.0))) < 5.0
    # with that vector, nothing is said
    right = RunConfig.model_validate({**CONFIG, "sim": {"grid": 24, "frames": 4}})
    note = prepare(scene, right.scene, right.sim, [], []).static_note
    assert note is None or "scene.up" not in note
