"""``video``: pixel agreement with a clip the prior generates (PhysDreamer's loss).

At construction the prior samples one reference clip for the run's prompt (deterministic
DDIM seeded with the run's seed; written to ``prior_reference.mp4``; shared with ``flow``
in the same run). Per call the rendered subsequence is resampled to the reference's frame
count and size and ``L = (1 − w) · mean((x − ref)²) + w · (1 − SSIM(x, ref))`` with
w = 0.9 (PhysDreamer's 0.1 L2 + 0.9 D-SSIM; SSIM as in ``video_match``: 11×11 Gaussian
window, σ 1.5). This module must not render or simulate.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction
from motionphysics.losses.prior_common import need_frames_prior, need_prior, reference_clip
from motionphysics.losses.video_match import ssim_map
from motionphysics.priors.base import resample_frames

__all__ = ["VideoLoss"]


class VideoLoss(Loss):
    """0.1 · L2 + 0.9 · (1 − SSIM) against the prior's sampled reference clip."""

    name: ClassVar[str] = "video"
    needs_render: ClassVar[bool] = True
    needs_prior: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: video, ...}]`` options."""

        model_config = ConfigDict(extra="forbid")

        ssim_weight: float = Field(default=0.9, ge=0.0, le=1.0)
        """w of the D-SSIM term; the L2 term has 1 − w (PhysDreamer: 0.9)."""
        sample_steps: int = Field(default=10, ge=1)
        """DDIM steps for the reference clip."""
        guidance: float = Field(default=6.0, ge=0.0)
        """CFG scale for *sampling* the reference clip (the pipelines' default 6; the
        distillation guidance of lmd / sds, 100, would ruin a sampled clip)."""

    def __init__(
        self,
        prior,
        prompt: str,
        options: VideoLoss.Options | None = None,
        *,
        seed: int = 0,
        out_dir=None,
        duration_s: float | None = None,
    ):
        self.opts = o = options or self.Options()
        need_frames_prior(self.name, prior)
        self.prior = need_prior(self.name, prior, prompt)
        self.reference = reference_clip(
            self.prior,
            prompt,
            steps=o.sample_steps,
            guidance=o.guidance,
            seed=seed,
            out_dir=out_dir,
            duration_s=duration_s,
        )  # [N, H, W, 3]
        self._last: dict[str, float] = {}

    @classmethod
    def build(cls, options, ctx: LossBuildContext) -> VideoLoss:
        duration = ctx.num_frames * ctx.frame_dt if ctx.num_frames and ctx.frame_dt else None
        return cls(
            ctx.prior, ctx.prompt, options, seed=ctx.seed, out_dir=ctx.out_dir, duration_s=duration
        )

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        if pred.rgb is None:
            raise ValueError("video needs rendered frames (Prediction.rgb)")
        n, h, w = self.reference.shape[:3]
        x = resample_frames(pred.rgb, n, h, w)
        ref = self.reference.to(x.device)
        l2 = ((x - ref) ** 2).mean()
        dssim = 1.0 - ssim_map(x, ref).mean()
        wgt = self.opts.ssim_weight
        loss = (1.0 - wgt) * l2 + wgt * dssim
        self._last = {"l2": float(l2.detach()), "dssim": float(dssim.detach())}
        return loss

    def components(self) -> dict[str, float]:
        return dict(self._last)
