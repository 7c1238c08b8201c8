"""A small analytic :class:`VideoPrior` for loss tests: a real implementation of the
interface on tiny data (linear encoder, linear "network"), so loss values can be computed
by hand from the same tensors."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from motionphysics.priors.base import TextEmbeddings, VideoPrior, resample_frames


class AnalyticPrior(VideoPrior):
    """encode: 2x2 average pool of ``2 x − 1`` per frame -> [1, F, 3, H/2, W/2];
    model_output: ``0.3 z_t + 0.01 t/1000 + text[:, 0, :3]`` per channel."""

    name = "analytic"

    def __init__(self, prediction_type="epsilon", num_frames=4, height=8, width=8):
        self.prediction_type = prediction_type
        self.num_frames, self.height, self.width = num_frames, height, width
        self.device = torch.device("cpu")
        self.dtype = torch.float32
        betas = torch.linspace(0.00085**0.5, 0.012**0.5, 1000, dtype=torch.float64) ** 2
        self.alphas_cumprod = torch.cumprod(1 - betas, 0).float()
        self._text = None

    @classmethod
    def from_pretrained(cls, path, *, device="cpu", dtype=None, **options):
        return cls(**options)

    def encode_text(self, prompt, negative_prompt=""):
        def emb(s):
            g = torch.Generator().manual_seed(sum(map(ord, s)) + 1)
            return torch.randn(1, 2, 3, generator=g)

        return TextEmbeddings(
            cond=emb(prompt),
            uncond=emb(negative_prompt),
            prompt=prompt,
            negative_prompt=negative_prompt,
        )

    def encode(self, frames: Tensor, generator=None) -> Tensor:
        x = resample_frames(frames, self.num_frames, self.height, self.width) * 2 - 1
        z = F.avg_pool2d(x.permute(0, 3, 1, 2), 2)  # [F, 3, h, w]
        return z.unsqueeze(0)

    def decode(self, latents: Tensor) -> Tensor:
        x = F.interpolate(latents[0], scale_factor=2, mode="nearest")
        return ((x + 1) / 2).permute(0, 2, 3, 1)

    def model_output(self, z_t, t, text):
        bias = text[:, 0, :3].view(-1, 1, 3, 1, 1)
        return 0.3 * z_t + 0.01 * (t.float() / 1000).view(-1, 1, 1, 1, 1) + bias
