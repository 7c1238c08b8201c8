"""``lmd``: learnable motion distillation (the MotionPhysics paper, Sec. 3.5, Eq. 4).

Per call (one optimisation iteration on one rendered subsequence):

1. ``z0 = E(frames)`` -- the prior's VAE encodes the (perturbed) renders, with grad;
2. ``t ~ U{t_min..t_max}`` (20..980), ``ε ~ N(0, I)``, ``z_t = √ᾱ z0 + √(1−ᾱ) ε``;
3. one guided prediction (no grad through the network) gives the one-step denoised
   ``x̂0`` (``prior.predict``: ε- or v-prediction, never dividing by √ᾱ for v);
4. the motion extractor ``M`` (two 1×1 convolutions with SiLU and GroupNorm, residual,
   zero-initialised output, so ``M`` is the identity at initialisation) maps both:
   ``y_pred = M(z0)`` (the online extractor, the gradient path to the renders) and
   ``y_target = M_ema(sg(x̂0))`` (its EMA copy on the detached x̂0);
5. ``L = w_k · sqrt(‖y_pred − y_target‖² + β²)`` with β = 1e-3 (Eq. 4, the paper's form);
6. the online extractor takes one AdamW step (lr 2e-5) on the same loss and the EMA copy
   follows (``ema ← 0.95 ema + 0.05 online``), as the released training loop does after
   its backward.

Where the paper and the released code (``wangmiaowei/MotionPhysics``
``trainning_scripts/motionphysics_train.py``, ``utils/headmlp.py``) differ, this follows
the paper and offers the code's choice as an option:

- Charbonnier: the paper takes the norm of the whole difference inside one square root
  (``charbonnier: paper``); the code sums an element-wise Charbonnier
  ``Σ (sqrt(d² + β²) − β)`` (``charbonnier: released``; the code further divides by its
  stage count 8, a constant the loss weight absorbs);
- ``w_k``: the paper weights by ``w_k`` (unspecified there); the code has no weight.
  Default ``weighting: uniform`` (w = 1, the code), or ``sds`` (1 − ᾱ_t), ``snr``;
- guidance: the paper says CFG = 100; the code applies ``v_c + 100 (v_c − v_u)``, which is
  101 in the diffusers form ``v_u + g (v_c − v_u)`` that ``guidance`` uses here;
- the code's extractor mixes the latent *frames* of CogVideoX latents (it was written for
  ModelScope's ``[b, c, t, h, w]`` and receives ``[b, t, c, h, w]``); here it mixes the
  latent *channels* per frame and position, as written;
- naming: the paper calls ``M(z̃0)`` the target and ``M(z̃_k^0)`` the prediction; which
  side is detached (x̂0) and which extractor is trained (the one on z0) follow the code.

``form: classifier_score`` replaces x̂0 in the target by ``z0 + (x̂0 − x̂0_uncond)``: only
the guided difference ``g (x̂0_c − x̂0_u)`` remains, so the part of the signal that
rewards clips that are merely easy to denoise (a prototype found the absolute loss pulls
every prompt toward "less motion": static, flattened clips are easier to denoise) cancels; with g = 0
the loss is flat. This is an option, not the paper's loss. Measured with an exact
(Gaussian, Bayes-optimal) prior in ``benchmarks/lmd_forms.py`` -- prompt mode m = 1,
unconditional mode 0, m optimised through this loss: ``absolute`` reaches 1.00 at g = 1,
3.61 at 7.5 and 4.11 at 100; ``classifier_score`` reaches 4.14 at every g (the maximiser
of the noisy likelihood ratio, averaged over t). So at the paper's g = 100 the two forms
nearly coincide; they differ at low guidance, where ``absolute`` keeps the "easy to
denoise" pull of an imperfect prior and ``classifier_score`` removes it.

The Gaussian perturbation (paper Suppl. D: centres ``+ ε N(0, I)``, SH coefficients
``+ 2ε N(0, I)``, ε = 0.1, drawn once per iteration and used only for this loss's render,
never for the simulation or the output) is a render-side concern for a prior that
observes frames: this loss exposes it as :attr:`LmdLoss.render_perturbation` for the
refinement stage to apply. For a prior that observes the simulated states (the motion
prior) the loss applies the geometry half itself: per iteration one offset
``ε L N(0, I)`` per particle [m] (``L``: the largest side of the rest state), drawn
from the loop's generator, is added to the observed positions and to the rest state;
there is no appearance to perturb.

What the loss reads of the prediction follows the prior (``prior.observes``): rendered
frames, or the simulated states of the supervised frames (then ``needs_render`` is
False and the loop does not render).

The extractor, its EMA copy and its optimiser are in :meth:`LmdLoss.state_dict`, so a
resumed run continues exactly. This module must not render or simulate.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import ClassVar, Literal

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor, nn

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

__all__ = ["LmdLoss", "MotionExtractor", "RenderPerturbation", "charbonnier"]


@dataclass(frozen=True)
class RenderPerturbation:
    """The Gaussian perturbation the refinement stage applies to the loss's render only.

    Drawn once per iteration (the same noise for every frame of the subsequence)."""

    centers: float
    """Std of the additive N(0, I) noise on the splat centres, in the units of the
    centres the renderer receives (paper: ε = 0.1 in its normalised simulation cube)."""
    sh: float
    """Std of the additive N(0, I) noise on every SH colour coefficient (paper: 2ε)."""


class MotionExtractor(nn.Module):
    """M: per-frame 1×1 conv mixer of latent channels with a residual, identity at init.

    ``x [B, F, C, h, w] -> (B·F, C, h, w) -> SiLU -> Conv1x1(C→hidden) -> GroupNorm ->
    SiLU -> Conv1x1(hidden→C, zero-initialised) -> + x`` (the released ``SpatialHead``
    with ``num_layers=2, kernel_size=1``; the residual adds the pre-SiLU input)."""

    def __init__(self, channels: int, hidden: int = 64, groups: int = 32):
        super().__init__()
        groups = max(1, min(groups, hidden))
        while hidden % groups:
            groups -= 1
        self.conv_in = nn.Conv2d(channels, hidden, kernel_size=1)
        self.norm = nn.GroupNorm(groups, hidden, eps=1e-5)
        self.conv_out = nn.Conv2d(hidden, channels, kernel_size=1)
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)

    def forward(self, x: Tensor) -> Tensor:
        b, f, c, h, w = x.shape
        flat = x.reshape(b * f, c, h, w)
        y = self.conv_in(nn.functional.silu(flat))
        y = self.conv_out(nn.functional.silu(self.norm(y)))
        return (y + flat).reshape(b, f, c, h, w)


def charbonnier(d: Tensor, beta: float, kind: str) -> Tensor:
    """``paper``: sqrt(‖d‖² + β²) (Eq. 4); ``released``: Σ (sqrt(d² + β²) − β)."""
    d = d if d.dtype == torch.float64 else d.float()
    if kind == "paper":
        return torch.sqrt((d * d).sum() + beta * beta)
    return (torch.sqrt(d * d + beta * beta) - beta).sum()


def _ema_update(ema: nn.Module, online: nn.Module, decay: float) -> None:
    with torch.no_grad():
        for pe, po in zip(ema.parameters(), online.parameters(), strict=True):
            pe.mul_(decay).add_(po, alpha=1.0 - decay)


class LmdLoss(Loss):
    """Learnable motion distillation against a video prior (see the module docstring)."""

    name: ClassVar[str] = "lmd"
    needs_render: ClassVar[bool] = True
    needs_prior: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: lmd, ...}]`` options."""

        model_config = ConfigDict(extra="forbid")

        guidance: float = Field(default=100.0, ge=0.0)
        """CFG scale g in ``out_u + g (out_c − out_u)`` (paper: 100)."""
        t_min: int = Field(default=20, ge=0)
        """Smallest diffusion step drawn (paper and code: 20)."""
        t_max: int = Field(default=980, ge=0)
        """Largest diffusion step drawn (paper and code: 980)."""
        weighting: Literal["uniform", "sds", "snr"] = "uniform"
        """w_k: ``uniform`` 1 (the released code), ``sds`` 1 − ᾱ_k, ``snr`` √(ᾱ/(1−ᾱ))."""
        beta: float = Field(default=1e-3, gt=0.0)
        """Charbonnier β (paper: 1e-3)."""
        charbonnier: Literal["paper", "released"] = "paper"
        """``paper``: sqrt(‖d‖² + β²); ``released``: Σ (sqrt(d² + β²) − β)."""
        form: Literal["absolute", "classifier_score"] = "absolute"
        """``absolute``: target M_ema(x̂0) (the paper); ``classifier_score``: target
        M_ema(z0 + x̂0 − x̂0_uncond), the guided difference only."""
        samples: int = Field(default=1, ge=1)
        """Diffusion draws (t, ε) per iteration, their losses averaged (1: the paper). The
        prior's predictions take no gradient, so K draws cost K prior calls and one
        backward; they cut the variance that the drawn t and ε add to the gradient."""
        negative_prompt: str = ""
        """The prompt the guidance is taken against: ``""`` (unconditional, the paper), a
        contrasting description (e.g. "a soft blob squashes flat" against "a stiff ball
        bounces high"), or ``auto``: the opposite motion with the prompt's subject
        (``language.captions.contrast_prompt``; ``""`` when the prompt claims no motion, or
        a wobble, which has no one opposite: too stiff and too soft both fail it).
        With ``form: classifier_score`` a contrasting prompt makes the loss the pairwise
        contrast ``x̂0(prompt) − x̂0(negative)``: the motion prior's default
        (``MotionPrior.loss_defaults``), and the form under which the removed pixel prior
        ordered simulated parameter sweeps the right way (BENCHMARKS.md; through ``run``
        it did not reach the direction bar)."""
        extractor_lr: float = Field(default=2e-5, ge=0.0)
        """AdamW learning rate of the online extractor (paper: 2e-5)."""
        ema_decay: float = Field(default=0.95, ge=0.0, le=1.0)
        """EMA rate of the target extractor (code: 0.95)."""
        extractor_hidden: int = Field(default=64, ge=1)
        """Hidden channels of the extractor (code: 64)."""
        extractor_groups: int = Field(default=32, ge=1)
        """GroupNorm groups (code: 32)."""
        train_extractor: bool = True
        """Train the online extractor (False: M stays the identity, a Charbonnier between
        z0 and x̂0, for ablations)."""
        perturbation: float = Field(default=0.1, ge=0.0)
        """ε of the render-side Gaussian perturbation (centres ε, SH 2ε; 0 disables);
        read by the refinement stage through ``render_perturbation``."""

    def __init__(self, prior, prompt: str, options: LmdLoss.Options | None = None, device="cpu"):
        self.opts = options or self.Options()
        self.prompt = prompt
        self.negative_prompt = resolve_negative(self.opts.negative_prompt, prompt)
        self.prior = need_prior(self.name, prior, prompt, self.negative_prompt)
        check_t_range(self.name, self.prior, self.opts.t_min, self.opts.t_max)
        states = observes_states(self.prior)
        self.needs_render = not states  # what the loop must produce for this prior
        self.needs_states = states
        channels = int(self.prior.latent_shape()[2])
        self.device = torch.device(getattr(self.prior, "device", device))
        self.extractor = MotionExtractor(
            channels, self.opts.extractor_hidden, self.opts.extractor_groups
        ).to(self.device)
        self.ema = copy.deepcopy(self.extractor).requires_grad_(False)
        self.optimizer = torch.optim.AdamW(
            self.extractor.parameters(),
            lr=self.opts.extractor_lr,
            betas=(0.9, 0.999),
            weight_decay=0.0,
            eps=1e-8,
        )
        eps = float(self.opts.perturbation)
        self.render_perturbation: RenderPerturbation | None = (
            RenderPerturbation(centers=eps, sh=2.0 * eps) if eps > 0 else None
        )
        self.steps = 0
        self._last: dict[str, float] = {}

    @classmethod
    def build(cls, options, ctx: LossBuildContext) -> LmdLoss:
        return cls(ctx.prior, ctx.prompt, options, device=ctx.device)

    # --- the loss ---------------------------------------------------------------------
    def _value(self, y_pred: Tensor, y_target: Tensor, w: Tensor) -> Tensor:
        return w * charbonnier(y_pred - y_target, self.opts.beta, self.opts.charbonnier)

    def _state_offset(self, ctx: LossContext) -> Tensor | None:
        """The geometry perturbation of a states prior's observation: [P, 3] m, or None."""
        if not self.needs_states or self.render_perturbation is None:
            return None
        rest = self.prior.scene.rest
        size = float((rest.max(0).values - rest.min(0).values).max())
        noise = torch.randn(tuple(rest.shape), generator=ctx.rng, dtype=torch.float32)
        return self.render_perturbation.centers * size * noise

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        prior, o = self.prior, self.opts
        # [1, F_lat, C, h, w], grad to the renders or the states
        z0 = observe(prior, pred, ctx.rng, self._state_offset(ctx))
        prior.set_prompt(self.prompt, self.negative_prompt)  # a shared prior may have another
        pdt = next(self.extractor.parameters()).dtype  # float32 (float64 in gradient checks)
        draws = []  # (t, w, y_target) per diffusion draw
        first = None  # the first draw's prediction (for the components)
        for _ in range(o.samples):
            t, noise = draw_t_noise(ctx.rng, tuple(z0.shape), o.t_min, o.t_max, z0.device)
            z_t = prior.add_noise(z0.detach(), noise, t)
            gp = prior.predict(z_t, t, o.guidance)
            if o.form == "absolute":
                target_latent = gp.x0
            else:
                target_latent = z0.detach() + (gp.x0 - gp.x0_uncond)
            with torch.no_grad():
                y_target = self.ema(target_latent.to(pdt))
            alpha_bar = prior.alphas_cumprod[t.long()].float().to(z0.device)
            draws.append((t, step_weight(o.weighting, alpha_bar).reshape(()), y_target))
            first = gp if first is None else first
        z0 = z0.to(pdt)
        (t, w, _), gp = draws[0], first

        def total(y_pred: Tensor) -> Tensor:
            return sum(self._value(y_pred, yt, wk) for _, wk, yt in draws) / len(draws)

        # The returned graph uses a snapshot of the extractor's weights, so the in-place
        # AdamW step below cannot invalidate it (the caller back-propagates later).
        snapshot = {k: v.detach().clone() for k, v in self.extractor.named_parameters()}
        y_pred = torch.func.functional_call(self.extractor, snapshot, (z0,))
        value = total(y_pred)

        if o.train_extractor and o.extractor_lr > 0:
            # The released loop's order: backward (extractor grads from the same loss),
            # AdamW step, then the EMA follows the updated online weights.
            self.optimizer.zero_grad(set_to_none=True)
            total(self.extractor(z0.detach())).backward()
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            _ema_update(self.ema, self.extractor, o.ema_decay)
        self.steps += 1
        with torch.no_grad():
            n = float(z0.numel())
            self._last = {
                "lmd": float(value.detach()),
                "t": float(t.item()),
                "w": float(w),
                "guidance": float(o.guidance),
                "samples": float(o.samples),
                "latent_gap_rms": float(((z0 - gp.x0) ** 2).sum().sqrt() / n**0.5),
                "guided_diff_rms": float(((gp.x0 - gp.x0_uncond) ** 2).sum().sqrt() / n**0.5),
            }
        return value

    def components(self) -> dict[str, float]:
        return dict(self._last)

    # --- checkpoint -------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "extractor": {
                k: v.detach().cpu().clone() for k, v in self.extractor.state_dict().items()
            },
            "ema": {k: v.detach().cpu().clone() for k, v in self.ema.state_dict().items()},
            "optimizer": copy.deepcopy(self.optimizer.state_dict()),
            "steps": self.steps,
        }

    def load_state_dict(self, state: dict) -> None:
        self.extractor.load_state_dict(state["extractor"])
        self.ema.load_state_dict(state["ema"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.steps = int(state.get("steps", 0))
