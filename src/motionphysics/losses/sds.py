"""``sds``: score distillation sampling against a video prior (DreamPhysics' form).

Per call: ``z0 = E(frames)`` with grad; ``t ~ U{t_min..t_max}`` (20..980), ``ε ~ N(0, I)``,
``z_t = √ᾱ z0 + √(1−ᾱ) ε``; one guided prediction (no grad through the network) gives ε̂;
``grad = w(t) (ε̂ − ε)`` with ``w = 1 − ᾱ_t``; and the detached-target form
``L = ½ Σ (z0 − sg(z0 − grad))²`` (DreamPhysics ``video_distillation/ms_guidance.py``), so
``dL/dz0 = grad`` exactly (the paper's Eq. 2–3). Non-finite entries of ``grad`` are zeroed
(``nan_to_num``) as DreamPhysics does.

DreamPhysics' guidance ``ε_c + 100 (ε_c − ε_u)`` is 101 in the diffusers form
``ε_u + g (ε_c − ε_u)`` that ``guidance`` uses here. For v-prediction priors ε̂ is derived
from v̂ without dividing by √ᾱ. ``form: classifier_score`` uses ``ε̂ − ε̂_uncond`` (the
guided difference) instead of ``ε̂ − ε`` (classifier score distillation).

The prior's observation (rendered frames, or the simulated states for a prior that
observes states) is what ``z0`` encodes. This module must not render or simulate.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction
from motionphysics.losses.prior_common import (
    check_t_range,
    draw_t_noise,
    need_prior,
    observe,
    observes_states,
    resolve_negative,
    step_weight,
)

__all__ = ["SdsLoss"]


class SdsLoss(Loss):
    """SDS with the detached-target form (see the module docstring)."""

    name: ClassVar[str] = "sds"
    needs_render: ClassVar[bool] = True
    needs_prior: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: sds, ...}]`` options."""

        model_config = ConfigDict(extra="forbid")

        guidance: float = Field(default=100.0, ge=0.0)
        """CFG scale g in ``ε_u + g (ε_c − ε_u)``."""
        t_min: int = Field(default=20, ge=0)
        """Smallest diffusion step drawn (DreamPhysics: 20)."""
        t_max: int = Field(default=980, ge=0)
        """Largest diffusion step drawn (DreamPhysics: 980)."""
        weighting: Literal["sds", "uniform", "snr"] = "sds"
        """w(t): ``sds`` 1 − ᾱ_t (DreamPhysics), ``uniform`` 1, ``snr`` √(ᾱ/(1−ᾱ))."""
        form: Literal["sds", "classifier_score"] = "sds"
        """``sds``: ε̂ − ε; ``classifier_score``: ε̂ − ε̂_uncond."""
        negative_prompt: str = ""
        """The prompt the guidance is taken against: ``""`` (unconditional, the paper), a
        contrasting description (e.g. "a soft blob squashes flat" against "a stiff ball
        bounces high"), or ``auto``: the opposite motion with the prompt's subject
        (``language.captions.contrast_prompt``; ``""`` when the prompt claims no motion, or
        a wobble, which has no one opposite: too stiff and too soft both fail it).
        With ``form: classifier_score`` a contrasting prompt makes the loss the pairwise
        contrast ``ε̂(prompt) − ε̂(negative)``: the motion prior's default
        (``MotionPrior.loss_defaults``), and the form under which the removed pixel prior
        ordered simulated parameter sweeps the right way (BENCHMARKS.md; through ``run``
        it did not reach the direction bar)."""

    def __init__(self, prior, prompt: str, options: SdsLoss.Options | None = None):
        self.opts = options or self.Options()
        self.prompt = prompt
        self.negative_prompt = resolve_negative(self.opts.negative_prompt, prompt)
        self.prior = need_prior(self.name, prior, prompt, self.negative_prompt)
        check_t_range(self.name, self.prior, self.opts.t_min, self.opts.t_max)
        self.needs_render = not observes_states(self.prior)  # frames, or the states
        self.needs_states = not self.needs_render
        self._last: dict[str, float] = {}

    @classmethod
    def build(cls, options, ctx: LossBuildContext) -> SdsLoss:
        return cls(ctx.prior, ctx.prompt, options)

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        prior, o = self.prior, self.opts
        z0 = observe(prior, pred, ctx.rng)  # [1, F_lat, C, h, w]: the frames or the states
        t, noise = draw_t_noise(ctx.rng, tuple(z0.shape), o.t_min, o.t_max, z0.device)
        z_t = prior.add_noise(z0.detach(), noise, t)
        prior.set_prompt(self.prompt, self.negative_prompt)  # a shared prior may have another
        gp = prior.predict(z_t, t, o.guidance)
        alpha_bar = prior.alphas_cumprod[t.long()].float().to(z0.device)
        w = step_weight(o.weighting, alpha_bar).reshape(())
        ref = noise if o.form == "sds" else gp.eps_uncond
        grad = torch.nan_to_num(w * (gp.eps - ref))
        target = (z0 - grad).detach()
        loss = 0.5 * ((z0 - target) ** 2).sum() / z0.shape[0]
        self._last = {
            "sds": float(loss.detach()),
            "t": float(t.item()),
            "w": float(w),
            "guidance": float(o.guidance),
            "grad_rms": float(grad.pow(2).mean().sqrt()),
        }
        return loss

    def components(self) -> dict[str, float]:
        return dict(self._last)
