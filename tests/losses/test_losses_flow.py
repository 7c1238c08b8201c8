"""``flow``: the Horn–Schunck estimator recovers known shifts, the loss is ½·MSE of the
flows, its pixel gradient matches central differences, the reference is sampled once and
written to prior_reference.mp4, RAFT fails with one line without torchvision, and two
iterations move the parameter on both diffusers priors."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "priors"))

from loss_helpers import (
    build,
    call,
    fd_check_pixel,
    moving_edge,
    tiny_prior,
    two_iterations_move_theta,
)  # noqa: E402

from motionphysics.errors import UserInputError  # noqa: E402
from motionphysics.losses.optical_flow import horn_schunck  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _texture(x, y):
    return 0.5 + 0.2 * torch.sin(x / 4 + 0.3 * y / 5) + 0.2 * torch.cos(y / 3.5 - x / 7)


@pytest.mark.parametrize("shift", [(0.5, -0.25), (1.5, 0.75), (3.0, -1.5), (6.0, 3.0)])
def test_horn_schunck_recovers_translation(shift):
    h = w = 64
    ys, xs = torch.meshgrid(torch.arange(h).float(), torch.arange(w).float(), indexing="ij")
    dx, dy = shift
    a = _texture(xs, ys)[..., None].expand(h, w, 3)[None]
    b = _texture(xs - dx, ys - dy)[..., None].expand(h, w, 3)[None]  # content moves by +d
    flow = horn_schunck(a, b)[0, :, 16:48, 16:48].mean((1, 2))
    assert float(flow[0]) == pytest.approx(dx, abs=0.03 * max(1, abs(dx)))
    assert float(flow[1]) == pytest.approx(dy, abs=0.03 * max(1, abs(dx)))


def test_horn_schunck_zero_for_identical_frames():
    a = torch.rand(2, 16, 16, 3, generator=torch.Generator().manual_seed(0))
    assert float(horn_schunck(a, a).abs().max()) < 1e-5  # grid_sample round-off only


def test_reference_written_and_value(tmp_path):
    from motionphysics.io.video import read_video

    prior = tiny_prior("cogvideox")
    loss = build("flow", prior, out_dir=tmp_path, sample_steps=2)
    ref = read_video(tmp_path / "prior_reference.mp4")
    assert ref.shape[0] == prior.num_frames and ref.shape[1:3] == (16, 16)
    rgb = moving_edge(torch.tensor(0.3), 6)
    value = call(loss, rgb)
    from motionphysics.priors.base import resample_frames

    fr = resample_frames(rgb, prior.num_frames, 16, 16)
    fl = loss.flow(fr[:-1], fr[1:])
    expected = 0.5 * float(((fl - loss.reference_flow) ** 2).mean())
    assert float(value) == pytest.approx(expected, rel=1e-6)
    assert loss.components()["flow_mse"] == pytest.approx(2 * expected, rel=1e-6)
    # the reference is sampled once per run: a second loss in the run reuses it
    again = build("flow", prior, out_dir=tmp_path, sample_steps=2)
    assert torch.equal(again.reference, loss.reference)


@pytest.mark.skipif(
    importlib.util.find_spec("torchvision") is not None, reason="torchvision is installed"
)
def test_raft_without_torchvision_is_one_line():
    with pytest.raises(UserInputError) as err:
        build("flow", tiny_prior("analytic"), estimator="raft", raft_weights="/nope.pth")
    assert "torchvision" in str(err.value) and "\n" not in str(err.value)


def test_gradient_matches_finite_differences():
    prior = tiny_prior("analytic")
    loss = build("flow", prior, sample_steps=2, detach_previous=False, iterations=10)
    loss.reference_flow = loss.reference_flow.double()
    rgb = moving_edge(torch.tensor(0.3, dtype=torch.float64), 4, 8, dtype=torch.float64)
    fd_check_pixel(lambda x: call(loss, x), rgb, h=1e-6, rtol=1e-5)


@pytest.mark.parametrize("kind", ["cogvideox", "modelscope"])
def test_two_iterations_move_theta(kind, tmp_path):
    loss = build("flow", tiny_prior(kind), out_dir=tmp_path, sample_steps=2)
    assert (tmp_path / "prior_reference.mp4").is_file()
    values, grads, theta = two_iterations_move_theta(loss)
    assert all(math.isfinite(v) for v in values)
    assert all(math.isfinite(g) and g != 0 for g in grads)
    assert theta != 0.4
