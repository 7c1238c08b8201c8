"""video_match: SSIM against a float64 reference twin, L1, the mask, errors, gradients."""

import numpy as np
import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.losses import LossContext, Prediction, available_losses, get_loss
from motionphysics.losses.video_match import VideoMatchLoss, ssim_map


def _ssim_reference(a: np.ndarray, b: np.ndarray, size=11, sigma=1.5) -> np.ndarray:
    """Direct float64 SSIM of one channel [H,W] with zero padding (the definition)."""
    c = np.arange(size) - (size - 1) / 2
    g = np.exp(-(c**2) / (2 * sigma**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    pad = size // 2
    ap, bp = np.pad(a, pad), np.pad(b, pad)
    out = np.zeros_like(a)
    c1, c2 = 0.01**2, 0.03**2
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            pa, pb = ap[i : i + size, j : j + size], bp[i : i + size, j : j + size]
            mx, my = (w * pa).sum(), (w * pb).sum()
            sxx = (w * pa * pa).sum() - mx**2
            syy = (w * pb * pb).sum() - my**2
            sxy = (w * pa * pb).sum() - mx * my
            out[i, j] = ((2 * mx * my + c1) * (2 * sxy + c2)) / (
                (mx**2 + my**2 + c1) * (sxx + syy + c2)
            )
    return out


def test_ssim_matches_reference_twin():
    rng = np.random.default_rng(0)
    a = rng.random((2, 12, 14, 3))
    b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    got = ssim_map(torch.tensor(a), torch.tensor(b)).numpy()
    for s in range(2):
        for ch in range(3):
            want = _ssim_reference(a[s, :, :, ch], b[s, :, :, ch])
            # float64 on both sides; only summation order differs.
            np.testing.assert_allclose(got[s, :, :, ch], want, atol=1e-10)


def test_identical_frames_give_zero_and_l1_is_exact():
    ref = torch.rand(5, 16, 16, 3)
    loss = VideoMatchLoss(ref)
    ctx = LossContext(iteration=0, num_frames=5)
    assert float(loss(Prediction((1, 3), rgb=ref[[1, 3]].clone()), ctx)) == pytest.approx(
        0.0, abs=1e-6
    )
    shifted = (ref[[2]] + 0.1).clamp(max=2.0)
    only_l1 = VideoMatchLoss(ref, ssim_weight=0.0)
    # Pure L1 of a constant offset of 0.1 is 0.1 (float32 rounding only).
    assert float(only_l1(Prediction((2,), rgb=shifted), ctx)) == pytest.approx(0.1, abs=1e-6)
    assert loss.components()["l1"] == pytest.approx(0.0, abs=1e-6)


def test_mask_ignores_pixels_outside():
    ref = torch.rand(3, 16, 16, 3)
    mask = torch.zeros(16, 16)
    mask[4:12, 4:12] = 1.0
    pred = ref[[1]].clone()
    pred[0, :2, :, :] = 0.0  # differs only outside the mask (and far from it for SSIM: 2 rows)
    masked = VideoMatchLoss(ref, mask=mask, ssim_weight=0.0)
    ctx = LossContext(iteration=0, num_frames=3)
    assert float(masked(Prediction((1,), rgb=pred), ctx)) == pytest.approx(0.0, abs=1e-7)
    assert float(VideoMatchLoss(ref, ssim_weight=0.0)(Prediction((1,), rgb=pred), ctx)) > 0.01
    pred[0, 6, 6, :] = 0.0
    assert float(masked(Prediction((1,), rgb=pred), ctx)) > 0.0


def test_gradient_matches_finite_differences():
    torch.manual_seed(0)
    ref = torch.rand(2, 9, 9, 3, dtype=torch.float64)
    loss = VideoMatchLoss(ref.float())
    loss.reference = ref  # float64 for a tight gradient check
    ctx = LossContext(iteration=0, num_frames=2)
    pred = torch.rand(1, 9, 9, 3, dtype=torch.float64, requires_grad=True)
    loss(Prediction((1,), rgb=pred), ctx).backward()
    for seed in range(3):  # directional derivatives along random directions
        v = torch.randn(
            pred.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(seed)
        )
        h = 1e-6
        with torch.no_grad():
            up = float(loss(Prediction((1,), rgb=pred + h * v), ctx))
            down = float(loss(Prediction((1,), rgb=pred - h * v), ctx))
        fd = (up - down) / (2 * h)
        # float64 central differences: truncation O(h^2) and round-off ~1e-16/h ~ 1e-10;
        # L1's kinks are met with probability ~0 at random points.
        assert float((pred.grad * v).sum()) == pytest.approx(fd, rel=1e-6, abs=1e-9)


def test_reference_checks_name_both_sides():
    loss = VideoMatchLoss(np.zeros((4, 10, 12, 3), np.uint8), source="ref.mp4")
    loss.check(4, 10, 12)
    with pytest.raises(
        UserInputError, match=r"ref.mp4: reference has 4 frames but config sim.frames is 6"
    ):
        loss.check(6, 10, 12)
    with pytest.raises(UserInputError, match=r"12x10 pixels .* 16x16"):
        loss.check(4, 16, 16)
    with pytest.raises(UserInputError, match="mask has shape"):
        VideoMatchLoss(np.zeros((4, 10, 12, 3)), mask=np.ones((3, 10, 12)))


def test_registry():
    assert {"video_match", "trajectory_match"} <= set(available_losses())
    assert get_loss("video_match") is VideoMatchLoss
    with pytest.raises(UserInputError, match="unknown loss 'nope'"):
        get_loss("nope")
