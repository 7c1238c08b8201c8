"""``flow``: optical-flow agreement with a clip the prior generates (PhysFlow's loss).

At construction the prior samples one reference clip for the run's prompt (deterministic
DDIM from a generator seeded with the run's seed; written to ``prior_reference.mp4``)
and its flow between consecutive frames is computed once. Per call the rendered
subsequence is resampled to the reference's frame count and size, its consecutive-frame
flow is estimated, and ``L = ½ · mean((flow_render − flow_ref)²)`` (PhysFlow
``0.5 · F.mse_loss``). As in PhysFlow the earlier frame of each rendered pair is detached
(``detach_previous``), so the gradient reaches each frame through one pair only.

Estimators (``estimator``): ``horn_schunck`` (default, differentiable torch, no weights;
:mod:`motionphysics.losses.optical_flow`) or ``raft`` (torchvision RAFT-large from the local
``raft_weights`` file; PhysFlow's choice; needs torchvision). PhysFlow's bounding-box crop
is not applied (the loss covers the frame). This module must not render or simulate.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction
from motionphysics.losses.optical_flow import RaftFlow, horn_schunck
from motionphysics.losses.prior_common import need_frames_prior, need_prior, reference_clip
from motionphysics.priors.base import resample_frames

__all__ = ["FlowLoss"]


class FlowLoss(Loss):
    """Consecutive-frame optical flow MSE against the prior's sampled reference clip."""

    name: ClassVar[str] = "flow"
    needs_render: ClassVar[bool] = True
    needs_prior: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: flow, ...}]`` options."""

        model_config = ConfigDict(extra="forbid")

        estimator: Literal["horn_schunck", "raft"] = "horn_schunck"
        """Flow estimator: differentiable Horn–Schunck (no weights) or RAFT (torchvision)."""
        raft_weights: str | None = None
        """Local path of torchvision's raft_large state dict (``estimator: raft`` only)."""
        sample_steps: int = Field(default=10, ge=1)
        """DDIM steps for the reference clip."""
        guidance: float = Field(default=6.0, ge=0.0)
        """CFG scale for *sampling* the reference clip (the pipelines' default 6; the
        distillation guidance of lmd / sds, 100, would ruin a sampled clip)."""
        flow_size: int | None = Field(default=None, ge=8)
        """Square side the flow is computed at (None: the prior's resolution)."""
        alpha: float = Field(default=0.05, gt=0.0)
        """Horn–Schunck smoothness weight (on [0, 1] intensities)."""
        iterations: int = Field(default=40, ge=1)
        """Horn–Schunck Jacobi iterations per pyramid level."""
        detach_previous: bool = True
        """Detach the earlier frame of each rendered pair (PhysFlow)."""

    def __init__(
        self,
        prior,
        prompt: str,
        options: FlowLoss.Options | None = None,
        *,
        seed: int = 0,
        out_dir=None,
        duration_s: float | None = None,
    ):
        self.opts = o = options or self.Options()
        need_frames_prior(self.name, prior)
        self.prior = need_prior(self.name, prior, prompt)
        self._raft = RaftFlow(o.raft_weights, self.prior.device) if o.estimator == "raft" else None
        ref = reference_clip(
            self.prior,
            prompt,
            steps=o.sample_steps,
            guidance=o.guidance,
            seed=seed,
            out_dir=out_dir,
            duration_s=duration_s,
        )  # [N, H, W, 3]
        if ref.shape[0] < 2:
            raise ValueError("flow needs a reference clip of at least 2 frames")
        self.size = (o.flow_size, o.flow_size) if o.flow_size else tuple(ref.shape[1:3])
        self.reference = resample_frames(ref, ref.shape[0], *self.size)
        with torch.no_grad():
            self.reference_flow = self.flow(
                self.reference[:-1], self.reference[1:]
            )  # [N-1, 2, h, w]
        self._last: dict[str, float] = {}

    @classmethod
    def build(cls, options, ctx: LossBuildContext) -> FlowLoss:
        duration = ctx.num_frames * ctx.frame_dt if ctx.num_frames and ctx.frame_dt else None
        return cls(
            ctx.prior, ctx.prompt, options, seed=ctx.seed, out_dir=ctx.out_dir, duration_s=duration
        )

    def flow(self, a: Tensor, b: Tensor) -> Tensor:
        """[N, H, W, 3] pairs -> [N, 2, H, W] flow in pixels."""
        if self._raft is not None:
            return self._raft(a, b)
        return horn_schunck(a, b, alpha=self.opts.alpha, iterations=self.opts.iterations)

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        if pred.rgb is None:
            raise ValueError("flow needs rendered frames (Prediction.rgb)")
        n = self.reference.shape[0]
        frames = resample_frames(pred.rgb, n, *self.size)
        prev = frames[:-1].detach() if self.opts.detach_previous else frames[:-1]
        fl = self.flow(prev, frames[1:])
        ref = self.reference_flow.to(fl.device)
        loss = 0.5 * ((fl - ref) ** 2).mean()
        self._last = {
            "flow_mse": float(loss.detach()) * 2.0,
            "flow_rms": float(fl.detach().pow(2).mean().sqrt()),
            "reference_flow_rms": float(ref.pow(2).mean().sqrt()),
        }
        return loss

    def components(self) -> dict[str, float]:
        return dict(self._last)
