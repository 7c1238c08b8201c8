"""``video_match``: L1 + SSIM of rendered frames against a reference video.

Used by system identification (``motionphysics fit``): the reference was rendered from
the same camera, so pixel agreement measures agreement of motion and shape. The loss
is ``(1 - w) * L1 + w * (1 - SSIM)`` (w = ``ssim_weight``, 0.2 as in 3D Gaussian
splatting), optionally weighted by a per-pixel mask in [0, 1] (e.g. the object's
silhouette, so a static background does not dilute the signal).

SSIM is the standard one (Wang et al. 2004): 11x11 Gaussian window, sigma 1.5,
C1 = 0.01^2, C2 = 0.03^2, zero padding, on each colour channel separately.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction

__all__ = ["VideoMatchLoss", "ssim_map", "as_float_frames"]


def as_float_frames(frames) -> Tensor:
    """[T,H,W,3] uint8 or float array/tensor -> float32 tensor in [0, 1]."""
    if isinstance(frames, np.ndarray):
        t = torch.from_numpy(np.ascontiguousarray(frames))
    else:
        t = torch.as_tensor(frames)
    if t.dtype == torch.uint8:
        return t.float() / 255.0
    return t.float()


def _gaussian_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32) -> Tensor:
    coords = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).to(dtype)  # [size, size]


def ssim_map(a: Tensor, b: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """Per-pixel SSIM of two image batches.

    a, b: [S, H, W, C] float in [0, 1]. Returns [S, H, W, C].
    """
    c = a.shape[-1]
    x = a.permute(0, 3, 1, 2)  # [S, C, H, W]
    y = b.permute(0, 3, 1, 2)
    w = _gaussian_window(window, sigma, a.dtype).to(a.device)
    w = w.expand(c, 1, window, window).contiguous()
    pad = window // 2

    def blur(t: Tensor) -> Tensor:
        return F.conv2d(t, w, padding=pad, groups=c)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x**2
    syy = blur(y * y) - mu_y**2
    sxy = blur(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2))
    return s.permute(0, 2, 3, 1)


class VideoMatchLoss(Loss):
    """L1 + SSIM against reference frames, optionally masked.

    reference: [T, H, W, 3] uint8 or float in [0, 1], one frame per run frame.
    mask: optional [T, H, W] (or [H, W], shared by all frames) weights in [0, 1].
    """

    name: ClassVar[str] = "video_match"
    needs_render: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: video_match, reference: FILE, ssim_weight: W}]``."""

        model_config = ConfigDict(extra="forbid")
        reference: str
        """Reference video (.mp4 / .gif, or .npz with ``frames`` and optionally ``mask``)
        rendered from the run camera, one frame per run frame."""
        ssim_weight: float = Field(0.2, ge=0, le=1)
        """Weight w of ``(1 - SSIM)`` in ``(1 - w) L1 + w (1 - SSIM)``."""

    @classmethod
    def build(cls, options: Options, ctx: LossBuildContext) -> VideoMatchLoss:
        """Read the reference of ``options`` and check it against the run of ``ctx``."""
        from motionphysics.io.reference import load_reference

        ref = load_reference(options.reference)
        if ref.kind != "video":
            raise UserInputError(
                f"{ref.path}: video_match needs a video reference (frames), got a trajectory"
            )
        loss = cls(ref.data, mask=ref.mask, ssim_weight=options.ssim_weight, source=ref.path)
        if ctx.num_frames and ctx.height and ctx.width:
            loss.check(ctx.num_frames, ctx.height, ctx.width, "the run config's")
        return loss

    def __init__(self, reference, mask=None, ssim_weight: float = 0.2, source: str = "reference"):
        ref = as_float_frames(reference)
        if ref.ndim != 4 or ref.shape[-1] != 3:
            raise UserInputError(
                f"{source}: expected frames of shape [frames, height, width, 3], got {tuple(ref.shape)}"
            )
        if not 0.0 <= ssim_weight <= 1.0:
            raise UserInputError(
                f"optimize.ssim_weight: expected a value in [0, 1], got {ssim_weight}"
            )
        self.reference = ref  # [T, H, W, 3]
        self.source = source
        self.ssim_weight = float(ssim_weight)
        self.mask: Tensor | None = None
        if mask is not None:
            m = torch.as_tensor(np.asarray(mask), dtype=torch.float32)
            if m.ndim == 2:
                m = m.expand(ref.shape[0], *m.shape)
            if tuple(m.shape) != tuple(ref.shape[:3]):
                raise UserInputError(
                    f"{source}: mask has shape {tuple(m.shape)}, expected {tuple(ref.shape[:3])} "
                    "(frames, height, width) like the frames"
                )
            self.mask = m.clamp(0.0, 1.0)
        self._last: dict[str, float] = {}

    def check(self, num_frames: int, height: int, width: int, config: str = "config") -> None:
        """Refuse a reference whose frame count or resolution differs from the run."""
        t, h, w = (int(s) for s in self.reference.shape[:3])
        if t != num_frames:
            raise UserInputError(
                f"{self.source}: reference has {t} frames but {config} sim.frames is {num_frames}"
            )
        if (h, w) != (height, width):
            raise UserInputError(
                f"{self.source}: reference is {w}x{h} pixels but {config} camera is "
                f"{width}x{height} (camera.width x camera.height)"
            )

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        if pred.rgb is None:
            raise ValueError("video_match needs rendered frames (Prediction.rgb)")
        idx = torch.as_tensor(pred.frame_indices, dtype=torch.long)
        ref = self.reference[idx].to(pred.rgb.device)
        diff = (pred.rgb - ref).abs()  # [S, H, W, 3]
        ssim = ssim_map(pred.rgb, ref)
        if self.mask is None:
            l1 = diff.mean()
            dssim = 1.0 - ssim.mean()
        else:
            m = self.mask[idx].to(pred.rgb.device)[..., None]  # [S, H, W, 1]
            denom = (m.sum() * 3).clamp_min(1e-8)
            l1 = (diff * m).sum() / denom
            dssim = ((1.0 - ssim) * m).sum() / denom
        loss = (1.0 - self.ssim_weight) * l1 + self.ssim_weight * dssim
        self._last = {"l1": float(l1.detach()), "dssim": float(dssim.detach())}
        return loss

    def components(self) -> dict[str, float]:
        return dict(self._last)
