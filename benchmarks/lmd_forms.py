"""Where do the LMD forms (and SDS) drive a "motion amount" when the prior is exact?

A measurement, not a test of the code's numerics. The prior is analytic: latents are
Gaussian, unconditional clips ``z ~ N(0, s_u² I)`` (most clips are nearly static: zero
motion) and clips of the prompt ``z ~ N(μ_c 1, s_c² I)``; its ε̂ is the exact posterior
mean of each Gaussian (the Bayes-optimal denoiser), so the only approximations left are
the losses' own. The "clip" is ``z0 = m·1`` and ``m`` (the motion amount, the prompt's
ideal is μ_c = 1) is optimised by Adam through the real ``lmd`` / ``sds`` losses.

    python benchmarks/lmd_forms.py            # prints one line per (loss, form, guidance)
"""

from __future__ import annotations

import torch

from motionphysics.losses.base import LossContext, Prediction
from motionphysics.losses.lmd import LmdLoss
from motionphysics.losses.sds import SdsLoss
from motionphysics.priors.base import TextEmbeddings, VideoPrior

MU_C, S_C, S_U = 1.0, 0.3, 0.6


class GaussianPrior(VideoPrior):
    name = "gaussian"
    prediction_type = "epsilon"

    def __init__(self):
        self.num_frames, self.height, self.width = 2, 4, 4
        self.device, self.dtype = torch.device("cpu"), torch.float64
        betas = torch.linspace(0.00085**0.5, 0.012**0.5, 1000, dtype=torch.float64) ** 2
        self.alphas_cumprod = torch.cumprod(1 - betas, 0)

    @classmethod
    def from_pretrained(cls, path, **kw):
        return cls()

    def encode_text(self, prompt, negative_prompt=""):
        return TextEmbeddings(cond=torch.ones(1, 1, 1), uncond=torch.zeros(1, 1, 1), prompt=prompt)

    def encode(self, frames, generator=None):
        return frames.permute(0, 3, 1, 2).unsqueeze(0)  # [1, T, 3, H, W]

    def decode(self, latents):
        return latents[0].permute(0, 2, 3, 1)

    def model_output(self, z_t, t, text):
        a = self.alphas_cumprod[t.long()].view(-1, 1, 1, 1, 1)
        cond = text[:, 0, 0].view(-1, 1, 1, 1, 1)
        mu = cond * MU_C
        s2 = cond * S_C**2 + (1 - cond) * S_U**2
        x0 = mu + a.sqrt() * s2 / (a * s2 + 1 - a) * (z_t - a.sqrt() * mu)
        return (z_t - a.sqrt() * x0) / (1 - a).sqrt()


def run(loss_cls, options, iters=300, m0=0.5, lr=0.02, seed=0):
    prior = GaussianPrior()
    loss = loss_cls(prior, "p", options)
    if isinstance(loss, LmdLoss):
        loss.extractor.double()
        loss.ema.double()
    m = torch.tensor(m0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([m], lr=lr)
    rng = torch.Generator().manual_seed(seed)
    tail = []
    for i in range(iters):
        rgb = m * torch.ones(2, 4, 4, 3, dtype=torch.float64)
        v = loss(
            Prediction(frame_indices=(0, 1), rgb=rgb),
            LossContext(iteration=i, num_frames=2, rng=rng),
        )
        opt.zero_grad()
        v.backward()
        opt.step()
        if i >= iters - 100:
            tail.append(float(m.detach()))
    return sum(tail) / len(tail)


def main():
    print(f"prompt mode mu_c = {MU_C}, unconditional mode 0; m starts at 0.5")
    for g in (1.0, 7.5, 30.0, 100.0):
        for form in ("absolute", "classifier_score"):
            m = run(LmdLoss, LmdLoss.Options(guidance=g, form=form, train_extractor=False))
            print(f"lmd  form={form:<17} g={g:>5}: m -> {m:+.3f}")
        for form in ("sds", "classifier_score"):
            m = run(SdsLoss, SdsLoss.Options(guidance=g, form=form))
            print(f"sds  form={form:<17} g={g:>5}: m -> {m:+.3f}")


if __name__ == "__main__":
    main()
