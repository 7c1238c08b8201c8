"""``video``: 0.1·L2 + 0.9·(1 − SSIM) against the prior's sampled reference (written to
prior_reference.mp4), a finite-difference pixel gradient, and two iterations on both
diffusers priors."""

from __future__ import annotations

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

from motionphysics.losses.video_match import ssim_map  # noqa: E402
from motionphysics.priors.base import resample_frames  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_value_matches_formula(tmp_path):
    prior = tiny_prior("modelscope")
    loss = build("video", prior, out_dir=tmp_path, sample_steps=2)
    assert (tmp_path / "prior_reference.mp4").is_file()
    assert loss.reference.shape == (prior.num_frames, 16, 16, 3)
    rgb = moving_edge(torch.tensor(0.3), 6)
    x = resample_frames(rgb, prior.num_frames, 16, 16)
    l2 = float(((x - loss.reference) ** 2).mean())
    dssim = 1 - float(ssim_map(x, loss.reference).mean())
    assert float(call(loss, rgb)) == pytest.approx(0.1 * l2 + 0.9 * dssim, rel=1e-6)
    assert loss.components() == pytest.approx({"l2": l2, "dssim": dssim}, rel=1e-6)
    # identical frames: zero loss
    assert float(call(loss, loss.reference.clone())) == pytest.approx(0.0, abs=1e-6)


def test_gradient_matches_finite_differences():
    prior = tiny_prior("analytic")
    loss = build("video", prior, sample_steps=2)
    loss.reference = loss.reference.double()
    rgb = moving_edge(torch.tensor(0.3, dtype=torch.float64), 4, 8, dtype=torch.float64)
    fd_check_pixel(lambda x: call(loss, x), rgb, h=1e-6, rtol=1e-5)


@pytest.mark.parametrize("kind", ["cogvideox", "modelscope"])
def test_two_iterations_move_theta(kind, tmp_path):
    loss = build("video", tiny_prior(kind), out_dir=tmp_path, sample_steps=2)
    values, grads, theta = two_iterations_move_theta(loss)
    assert all(math.isfinite(v) for v in values)
    assert all(math.isfinite(g) and g != 0 for g in grads)
    assert theta != 0.4
