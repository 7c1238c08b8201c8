"""The frames the viewer serves equal the renderer's deformation (render.deform) of the run.

Checked three ways on a tiny real run (made by ``motionphysics simulate``), with a
degree-1 SH scene so view-dependent colour is exercised: the served buffer (decoded)
against ``deform_splats`` within the wire's precision (float32 centres, float16
relative covariances, 8-bit colours); :class:`FrameSource` against ``deform_splats``
at float32 rounding; and both against a float64 NumPy/SciPy twin written from the
formulas (centre ``x_p + F_p o``, covariance ``F Σ Fᵀ``, colour along ``Rᵀ d`` with
``R`` the polar rotation of ``F``).
"""

from __future__ import annotations

import io
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from chromium_cdp import free_port  # noqa: E402


@pytest.fixture(scope="module")
def sh1_run(tiny_run, tmp_path_factory) -> Path:
    """The tiny run with its rest splats given random degree-1 SH (view-dependent colour)."""
    from motionphysics.scene.gaussians import GaussianScene
    from motionphysics.scene.ply import read_ply, write_ply

    out = tmp_path_factory.mktemp("sh1") / "run"
    shutil.copytree(tiny_run, out)
    s = read_ply(out / "scene.ply")
    g = torch.Generator().manual_seed(3)
    rest = 0.6 * torch.randn((s.num, 3, 3), generator=g)
    sh = torch.cat([s.sh, rest], dim=1)
    write_ply(
        GaussianScene(s.means, s.log_scales, s.quats, s.logit_opacities, sh), out / "scene.ply"
    )
    return out


def _reference(run, k: int, camera):
    from motionphysics.render.deform import deform_splats

    x = torch.from_numpy(np.array(run.x[k]))
    F = torch.from_numpy(np.array(run.F[k]))
    with torch.no_grad():
        m, c, col = deform_splats(
            run.splats, x, F, torch.from_numpy(run.parent), torch.from_numpy(run.offset), camera
        )
    return m.numpy(), c.numpy(), col.clamp(0, 1).numpy()


def _twin(run, k: int, camera_pos: np.ndarray):
    """float64 NumPy/SciPy twin of the deformation (no motionphysics.render code)."""
    from scipy.linalg import polar

    x = np.asarray(run.x[k], np.float64)
    F = np.asarray(run.F[k], np.float64)[run.parent]
    means = x[run.parent] + np.einsum("nij,nj->ni", F, run.offset.astype(np.float64))
    q = run.splats.quats.numpy().astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, a, b, c = q.T
    Rq = np.stack(
        [
            np.stack([1 - 2 * (b * b + c * c), 2 * (a * b - w * c), 2 * (a * c + w * b)], -1),
            np.stack([2 * (a * b + w * c), 1 - 2 * (a * a + c * c), 2 * (b * c - w * a)], -1),
            np.stack([2 * (a * c - w * b), 2 * (b * c + w * a), 1 - 2 * (a * a + b * b)], -1),
        ],
        -2,
    )
    s2 = np.exp(2 * run.splats.log_scales.numpy().astype(np.float64))
    sigma = np.einsum("nij,nj,nkj->nik", Rq, s2, Rq)
    covs = F @ sigma @ np.swapaxes(F, 1, 2)
    R = np.stack([polar(f)[0] for f in F])
    d = means - camera_pos
    d_rest = np.einsum("nji,nj->ni", R, d)  # R^T d
    d_rest /= np.linalg.norm(d_rest, axis=1, keepdims=True)
    sh = run.splats.sh.numpy().astype(np.float64)
    C0, C1 = 0.28209479177387814, 0.4886025119029199
    X, Y, Z = d_rest[:, 0:1], d_rest[:, 1:2], d_rest[:, 2:3]
    rgb = 0.5 + C0 * sh[:, 0] - C1 * Y * sh[:, 1] + C1 * Z * sh[:, 2] - C1 * X * sh[:, 3]
    return means, covs, np.clip(rgb, 0, 1)


def test_frame_source_equals_render_deform_and_twin(sh1_run):
    from motionphysics.viewer.frames import FrameSource
    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import _camera_view

    run = load_run(sh1_run)
    assert run.splats.sh_degree == 1
    cam = _camera_view(run.config)["camera"]
    src = FrameSource(run, cam)
    for k in (0, run.num_frames // 2, run.num_frames - 1):
        fr = src.frame(k)
        m, c, col = _reference(run, k, cam)
        np.testing.assert_allclose(fr.means, m, rtol=0, atol=1e-6)
        np.testing.assert_allclose(fr.covs, c, rtol=1e-5, atol=1e-12)
        np.testing.assert_allclose(fr.colors, col, rtol=0, atol=1e-5)
        tm, tc, tcol = _twin(run, k, cam.position.numpy())
        np.testing.assert_allclose(fr.means, tm, rtol=0, atol=2e-6)
        scale = np.abs(tc).reshape(len(tc), -1).max(1)[:, None, None]
        np.testing.assert_allclose(fr.covs / scale, tc / scale, rtol=0, atol=1e-5)
        np.testing.assert_allclose(fr.colors, tcol, rtol=0, atol=2e-4)
        np.testing.assert_allclose(fr.opacities[:, 0], run.splats.opacities.numpy(), atol=0)
    # The run moves: a later frame is not the first one.
    assert np.abs(src.frame(run.num_frames - 1).means - src.frame(0).means).max() > 0.05


def test_served_buffer_matches_render_deform(sh1_run):
    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import Viewer, _camera_view

    run = load_run(sh1_run)
    cam = _camera_view(run.config)["camera"]
    out = io.StringIO()
    viewer = Viewer([run], port=free_port(), frame=2, out=out)
    viewer.start()
    try:
        for k in (2, run.num_frames - 1, 0):
            if k != 2:
                viewer.show_frame(k)
            served = viewer.served_frame()
            assert served.index == k
            m, c, col = _reference(run, k, cam)
            np.testing.assert_allclose(served.means, m, rtol=0, atol=2e-6)
            # float16 on the wire: ~1e-3 of each splat's largest covariance entry.
            scale = np.abs(c).reshape(len(c), -1).max(1)[:, None, None]
            np.testing.assert_allclose(served.covs / scale, c / scale, rtol=0, atol=2e-3)
            np.testing.assert_allclose(served.colors, col, rtol=0, atol=1.01 / 255)
            np.testing.assert_allclose(
                served.opacities, run.splats.opacities.numpy(), rtol=0, atol=1.01 / 255
            )
    finally:
        viewer.stop()
    assert f"http://127.0.0.1:{viewer.port}" in out.getvalue()


def test_subsampled_frames_are_rows_of_the_full_frame(tiny_run):
    from motionphysics.viewer.frames import FrameSource
    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import Viewer, _camera_view

    run = load_run(tiny_run)
    cam = _camera_view(run.config)["camera"]
    full = FrameSource(run, cam, max_splats=None).frame(5)
    sub = FrameSource(run, cam, max_splats=700)
    assert sub.subsampled and sub.num_shown == 700
    fr = sub.frame(5)
    idx = sub.indices
    assert np.all(np.diff(idx) > 0)
    np.testing.assert_allclose(fr.means, full.means[idx], atol=1e-6)
    np.testing.assert_allclose(fr.covs, full.covs[idx], rtol=1e-5, atol=1e-12)
    # Said on stdout when the viewer starts.
    out = io.StringIO()
    viewer = Viewer([run], port=free_port(), max_splats=700, out=out)
    viewer.start()
    viewer.stop()
    text = out.getvalue()
    assert "streamed one at a time" in text and f"showing 700 of {run.num_splats}" in text


def test_npz_members_are_memory_mapped(tmp_path):
    from motionphysics.viewer.rundata import npz_member

    a = np.arange(2 * 5 * 3, dtype=np.float32).reshape(2, 5, 3)
    b = np.arange(7, dtype=np.int64)
    np.savez(tmp_path / "s.npz", a=a, b=b, z=np.zeros((0, 3)))
    np.savez_compressed(tmp_path / "c.npz", a=a)
    m = npz_member(tmp_path / "s.npz", "a")
    assert isinstance(m, np.memmap)
    np.testing.assert_array_equal(m, a)
    np.testing.assert_array_equal(npz_member(tmp_path / "s.npz", "b"), b)
    assert npz_member(tmp_path / "s.npz", "z").shape == (0, 3)
    c = npz_member(tmp_path / "c.npz", "a")
    assert not isinstance(c, np.memmap)
    np.testing.assert_array_equal(c, a)


def test_runs_switch_and_play_advances(tiny_run, sh1_run):
    import time

    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import Viewer, _camera_view

    runs = [load_run(tiny_run), load_run(sh1_run)]
    viewer = Viewer(runs, port=free_port(), frame=1, out=io.StringIO())
    viewer.start()
    try:
        assert viewer.served_frame().run == 0
        viewer.select_run(1)
        served = viewer.served_frame()
        assert served.run == 1 and served.index == 1
        _, _, col = _reference(runs[1], 1, _camera_view(runs[1].config)["camera"])
        np.testing.assert_allclose(served.colors, col, atol=1.01 / 255)
        # Play: frames follow one another at about real time (frame_dt 0.04 s), looping.
        seen = set()
        viewer._set_playing(True)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            seen.add(viewer.served_frame().index)
            time.sleep(0.01)
        viewer._set_playing(False)
        assert len(seen) == runs[1].num_frames  # 8 frames in 1 s at 25 frames/s: all of them
    finally:
        viewer.stop()


def test_run_without_scene_ply_is_prepared_again(tiny_run, tmp_path):
    from motionphysics.scene.ply import read_ply
    from motionphysics.viewer.rundata import load_run

    run = tmp_path / "old"
    shutil.copytree(tiny_run, run)
    (run / "scene.ply").unlink()
    notes: list[str] = []
    data = load_run(run, notes)
    ref = read_ply(tiny_run / "scene.ply")
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
        np.testing.assert_allclose(getattr(data.splats, name), getattr(ref, name), atol=1e-6)
    assert len(notes) == 1 and "no scene.ply" in notes[0]


def _donut() -> Path | None:
    """The real 3DGS capture (shared/data/real/donut.ply beside the repository)."""
    import os

    roots = [Path(__file__).resolve().parents[2].parent / "shared"]
    if os.environ.get("MOTIONPHYSICS_SHARED"):
        roots.insert(0, Path(os.environ["MOTIONPHYSICS_SHARED"]))
    for root in roots:
        path = root / "data" / "real" / "donut.ply"
        if path.is_file():
            return path
    return None


@pytest.mark.skipif(_donut() is None, reason="real capture shared/data/real/donut.ply not present")
def test_real_capture_run_served_as_rendered(tmp_path):
    """A run of the real donut capture (45k splats) made by the CLI: served = render.deform."""
    from viewer_runs import make_run

    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import Viewer, _camera_view

    cfg = tmp_path / "donut.yaml"
    cfg.write_text(
        f"scene: {{source: '{_donut()}', translate: [0, 0, 0.05], max_particles: 1500}}\n"
        "prompt: 'A soft donut drops onto the table.'\n"
        "material: {class: elastic, density: 800, E: 2.0e5, nu: 0.3}\n"
        "sim: {grid: 16, frames: 4, frame_dt: 0.04, substeps: auto}\n"
        "boundary_conditions:\n"
        "  - {type: surface_collider, point: [0, 0, 0], normal: [0, 0, 1], mode: sticky}\n"
        "camera: {width: 64, height: 48}\n"
    )
    run = load_run(make_run(cfg, tmp_path / "run"))
    assert run.num_splats > 10_000
    cam = _camera_view(run.config)["camera"]
    viewer = Viewer([run], port=free_port(), frame=run.num_frames - 1, out=io.StringIO())
    viewer.start()
    try:
        served = viewer.served_frame()
        m, c, col = _reference(run, run.num_frames - 1, cam)
        np.testing.assert_allclose(served.means, m, rtol=0, atol=2e-6)
        scale = np.abs(c).reshape(len(c), -1).max(1)[:, None, None]
        np.testing.assert_allclose(served.covs / scale, c / scale, rtol=0, atol=2e-3)
        np.testing.assert_allclose(served.colors, col, rtol=0, atol=1.01 / 255)
    finally:
        viewer.stop()
