"""The one interface every diffusion motion prior implements (:class:`VideoPrior`).

A prior declares what it observes (``observes``): ``frames`` (the rendered frames of the
supervised subsequence: CogVideoX, ModelScope) or ``states`` (the simulated particle
states of those frames: the embedded motion prior). It turns what it
observes into latents (differentiably: :meth:`VideoPrior.encode` for frames,
:meth:`VideoPrior.encode_states` for states), adds noise on its own schedule, and
predicts both the clean latent x̂0 and the noise ε̂ from a noisy latent, with
classifier-free guidance applied as the diffusers pipelines apply it. The losses
(``lmd``, ``sds``, ``flow``, ``video``) use only this interface (through
``losses.prior_common.observe``), and the optimisation loop renders only when some
loss's prior observes frames, so a backend is one module.

A prior that observes states is told the run's scene once (:meth:`VideoPrior.set_scene`:
the rest positions, the ground, the gravity, the time between frames), as it is told
the prompt.

Conventions (shared by every backend):

- frames: ``[T, H, W, 3]`` float32 in [0, 1] (what the renderer produces);
- latents: ``[B, F_lat, C, h, w]`` (the CogVideoX pipeline layout); a backend whose
  network wants another layout (the VAE's ``[B, C, F, H, W]``, ModelScope's UNet) permutes
  inside its own ``encode`` / ``model_output``;
- timesteps: integer tensors ``[B]`` in ``[0, num_train_timesteps)``;
- ``alphas_cumprod``: ``[num_train_timesteps]`` float32 (ᾱ_t);
- the forward process ``x_t = √ᾱ z + √(1−ᾱ) ε``.

x̂0 and ε̂ are derived from the network output without ever dividing by √ᾱ for
v-prediction (CogVideoX's zero-terminal-SNR end has ᾱ_999 = 0):
``x̂0 = √ᾱ x_t − √(1−ᾱ) v̂``, ``ε̂ = √ᾱ v̂ + √(1−ᾱ) x_t``.
For epsilon-prediction ``x̂0 = (x_t − √(1−ᾱ) ε̂) / √ᾱ`` (ᾱ ≥ 0.0046 on ModelScope's
schedule, so the division is safe there). For x0-prediction (``sample``, the motion
prior) ``ε̂ = (x_t − √ᾱ x̂0) / √(1−ᾱ)``.

This module must not import diffusers or transformers.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Literal

import torch
from torch import Tensor

__all__ = [
    "GuidedPrediction",
    "SceneContext",
    "TextEmbeddings",
    "VideoPrior",
    "resample_frames",
]

PredictionType = Literal["epsilon", "v_prediction", "sample"]
Observes = Literal["frames", "states"]


@dataclass(frozen=True)
class SceneContext:
    """What a prior that observes simulated states needs to know of the run's scene."""

    rest: Tensor
    """[P, 3] float32 rest positions of the simulated particles (frame 0) [m], world."""
    ground: float | None
    """Height of the ground under the object along "up" [m]; None: no ground."""
    gravity: tuple[float, float, float]
    """[m/s^2]."""
    frame_dt: float
    """Seconds between output frames (frame k is at time k * frame_dt)."""


def resample_frames(frames: Tensor, num_frames: int, height: int, width: int) -> Tensor:
    """[T, H, W, 3] -> [num_frames, height, width, 3], differentiable.

    Space: bilinear (``align_corners=False``, what the released MotionPhysics code uses to
    bring renders to 256²; the aspect ratio is not preserved). Time: linear with the first
    and last frames kept (``align_corners=True``), so a clip keeps its start and end
    states whatever its frame count. Identity when the shape already matches.
    """
    import torch.nn.functional as F

    if frames.dim() != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [T, H, W, 3], got {tuple(frames.shape)}")
    x = frames.permute(3, 0, 1, 2).unsqueeze(0)  # [1, 3, T, H, W]
    t, h, w = x.shape[2:]
    if (h, w) != (height, width):
        flat = x.permute(0, 2, 1, 3, 4).reshape(t, 3, h, w)
        flat = F.interpolate(flat, size=(height, width), mode="bilinear", align_corners=False)
        x = flat.reshape(1, t, 3, height, width).permute(0, 2, 1, 3, 4)
    if t != num_frames:
        if t == 1:
            x = x.expand(-1, -1, num_frames, -1, -1)
        else:
            x = F.interpolate(
                x, size=(num_frames, height, width), mode="trilinear", align_corners=True
            )
    return x.squeeze(0).permute(1, 2, 3, 0)


@dataclass(frozen=True)
class TextEmbeddings:
    """Encoded prompt, computed once per run (the text encoder may then be released)."""

    cond: Tensor
    """[1, L, D] conditional token embeddings."""
    uncond: Tensor
    """[1, L, D] unconditional (negative-prompt) token embeddings."""
    prompt: str
    negative_prompt: str = ""


@dataclass(frozen=True)
class GuidedPrediction:
    """One guided denoising prediction at timestep ``t``."""

    x0: Tensor
    """[B, F_lat, C, h, w] predicted clean latent x̂0 (guided)."""
    eps: Tensor
    """[B, F_lat, C, h, w] predicted noise ε̂ (guided)."""
    eps_cond: Tensor
    """[B, F_lat, C, h, w] conditional ε̂ (no guidance)."""
    eps_uncond: Tensor
    """[B, F_lat, C, h, w] unconditional ε̂."""
    t: Tensor
    """[B] the timesteps used."""
    x0_cond: Tensor | None = None
    """[B, F_lat, C, h, w] conditional x̂0 (no guidance)."""
    x0_uncond: Tensor | None = None
    """[B, F_lat, C, h, w] unconditional x̂0 (so ``x0 - x0_uncond`` is the guided difference
    ``g (x̂0_c - x̂0_u)`` of the classifier-score forms)."""


class VideoPrior(ABC):
    """A text-to-video diffusion model used as a motion prior.

    Subclasses set the attributes below in their constructor and implement
    :meth:`from_pretrained`, :meth:`encode_text`, :meth:`encode`, :meth:`decode` and
    :meth:`model_output`. The generic parts (noise, guidance, x̂0 / ε̂, DDIM sampling)
    live here so every backend computes them the same way.
    """

    loss_defaults: ClassVar[dict[str, dict[str, object]]] = {}
    """Per loss name, options the loss takes with this prior unless the config sets
    them (``optimize.losses[].*`` and ``--guidance`` win); the paper's defaults when
    empty."""

    unreadable: ClassVar[dict[str, str]] = {}
    """Material parameters the prior cannot tell apart from words, each with the one line a
    run that refines it warns with (``optimize.refine.prior_limits``); empty: none known."""

    name: ClassVar[str] = "prior"
    observes: ClassVar[Observes] = "frames"
    """What the prior looks at: ``frames`` (rendered, :meth:`encode`) or ``states`` (the
    simulated positions and deformation gradients of the supervised frames,
    :meth:`encode_states`; the loop then does not render for it)."""
    prediction_type: PredictionType
    """What the network predicts: ``epsilon`` (ModelScope), ``v_prediction`` (CogVideoX) or
    ``sample`` (the motion prior)."""
    num_frames: int
    """Frames per clip the prior is run at (rendered subsequences are resampled to this)."""
    height: int
    """Pixel height the prior is run at."""
    width: int
    """Pixel width the prior is run at."""
    device: torch.device
    dtype: torch.dtype
    """Dtype of the networks (float32 on CPU; bf16 / fp16 on CUDA)."""
    alphas_cumprod: Tensor
    """[num_train_timesteps] float32 ᾱ_t on ``device``."""

    _text: TextEmbeddings | None = None
    _scene: SceneContext | None = None

    # --- what a backend implements -------------------------------------------------
    @classmethod
    @abstractmethod
    def from_pretrained(
        cls, path: str | None, *, device: str = "cpu", dtype: torch.dtype | None = None, **options
    ) -> VideoPrior:
        """Load from ``path`` (a diffusers-layout directory, a hub id, or None for an
        embedded default). Missing or wrong components raise ``UserInputError`` naming
        what is missing and how to get it."""

    @abstractmethod
    def encode_text(self, prompt: str, negative_prompt: str = "") -> TextEmbeddings:
        """Encode ``prompt`` and ``negative_prompt`` with the prior's text encoder."""

    @abstractmethod
    def encode(self, frames: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """[T, H, W, 3] frames in [0, 1] -> [1, F_lat, C, h, w] scaled latents, differentiable.

        Resizes to ``(height, width)`` and resamples to ``num_frames`` first. A VAE with a
        Gaussian posterior draws its sample from ``generator`` (so a loss that fixes its
        generator is deterministic)."""

    def encode_states(
        self,
        xs: Tensor,
        Fs: Tensor,
        frame_indices: tuple[int, ...],
        offset: Tensor | None = None,
    ) -> Tensor:
        """States of the supervised frames -> ``[1, F_lat, C, h, w]`` latents, differentiable
        in ``xs`` [S, P, 3] m and ``Fs`` [S, P, 3, 3] (``frame_indices`` [S]: their run
        frame indices, ascending, > 0). ``offset`` [P, 3] m: the geometry perturbation the
        caller added to ``xs``, to be added to the rest state too. Only priors with
        ``observes = "states"``."""
        raise NotImplementedError(f"prior {self.name} observes rendered frames, not states")

    def set_scene(self, scene: SceneContext) -> None:
        """Tell a prior that observes states the run's scene (once per run)."""
        self._scene = scene

    @property
    def scene(self) -> SceneContext:
        if self._scene is None:
            raise RuntimeError("VideoPrior.set_scene() must be called before encode_states")
        return self._scene

    @abstractmethod
    def decode(self, latents: Tensor) -> Tensor:
        """[1, F_lat, C, h, w] scaled latents -> [num_frames, height, width, 3] in [0, 1]."""

    @abstractmethod
    def model_output(self, z_t: Tensor, t: Tensor, text: Tensor) -> Tensor:
        """Raw network output (ε̂ or v̂, per ``prediction_type``) for ``z_t`` [B, F_lat, C, h, w],
        ``t`` [B] and token embeddings ``text`` [B, L, D]. Runs without building a graph
        through the network unless the caller enabled grad."""

    # --- shared -----------------------------------------------------------------------
    @property
    def num_train_timesteps(self) -> int:
        return int(self.alphas_cumprod.shape[0])

    def set_prompt(self, prompt: str, negative_prompt: str = "") -> TextEmbeddings:
        """Encode and cache the prompt (once per run); returns the cached embeddings."""
        if self._text is None or (self._text.prompt, self._text.negative_prompt) != (
            prompt,
            negative_prompt,
        ):
            self._text = self.encode_text(prompt, negative_prompt)
        return self._text

    @property
    def text(self) -> TextEmbeddings:
        if self._text is None:
            raise RuntimeError("VideoPrior.set_prompt() must be called before predicting")
        return self._text

    def _alpha(self, t: Tensor, like: Tensor) -> Tensor:
        a = self.alphas_cumprod.to(like.device)[t.long()].to(torch.float32)
        return a.view(-1, *([1] * (like.dim() - 1)))

    def add_noise(self, z0: Tensor, noise: Tensor, t: Tensor) -> Tensor:
        """x_t = √ᾱ_t z0 + √(1−ᾱ_t) ε."""
        a = self._alpha(t, z0)
        return a.sqrt() * z0 + (1.0 - a).sqrt() * noise

    def to_x0_eps(self, out: Tensor, z_t: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """(x̂0, ε̂) from a network output, per ``prediction_type``."""
        a = self._alpha(t, z_t)
        if self.prediction_type == "sample":
            return out, (z_t - a.sqrt() * out) / (1.0 - a).sqrt().clamp_min(1e-4)
        if self.prediction_type == "v_prediction":
            return a.sqrt() * z_t - (1.0 - a).sqrt() * out, a.sqrt() * out + (1.0 - a).sqrt() * z_t
        return (z_t - (1.0 - a).sqrt() * out) / a.sqrt(), out

    def predict(self, z_t: Tensor, t: Tensor, guidance: float) -> GuidedPrediction:
        """Guided x̂0 and ε̂ for ``z_t`` at ``t`` (no graph through the network).

        Guidance as the diffusers pipelines apply it: ``out = out_u + g (out_c − out_u)``
        on the raw output (v or ε), one batched call over [uncond; cond]."""
        text = self.text
        b = z_t.shape[0]
        # Guidance arithmetic in float32 (float64 when the caller works in float64, as
        # gradient checks do), whatever the network's dtype, as the pipelines do.
        ft = torch.float64 if z_t.dtype == torch.float64 else torch.float32
        with torch.no_grad():
            emb = torch.cat([text.uncond.expand(b, -1, -1), text.cond.expand(b, -1, -1)])
            raw = self.model_output(torch.cat([z_t, z_t]), torch.cat([t, t]), emb).to(ft)
            out_u, out_c = raw.chunk(2)
            out = out_u + guidance * (out_c - out_u)
            zf = z_t.to(ft)
            x0, eps = self.to_x0_eps(out, zf, t)
            x0_c, eps_c = self.to_x0_eps(out_c, zf, t)
            x0_u, eps_u = self.to_x0_eps(out_u, zf, t)
        return GuidedPrediction(
            x0=x0, eps=eps, eps_cond=eps_c, eps_uncond=eps_u, t=t, x0_cond=x0_c, x0_uncond=x0_u
        )

    def latent_shape(self) -> tuple[int, ...]:
        """[1, F_lat, C, h, w] of one clip's latent (from encoding a black clip)."""
        with torch.no_grad():
            z = self.encode(torch.zeros(self.num_frames, self.height, self.width, 3))
        return tuple(z.shape)

    def sample(
        self, *, steps: int = 10, guidance: float = 6.0, generator: torch.Generator | None = None
    ) -> Tensor:
        """A clip generated for the cached prompt by deterministic DDIM (η = 0) over
        ``steps`` trailing timesteps -> [num_frames, height, width, 3] in [0, 1]."""
        shape = self.latent_shape()
        z = torch.randn(shape, generator=generator).to(self.device)
        n = self.num_train_timesteps
        ts = torch.linspace(n - 1, 0, steps).round().long()
        for i, t in enumerate(ts):
            tt = t.view(1).to(self.device)
            pred = self.predict(z, tt, guidance)
            a_prev = self.alphas_cumprod[ts[i + 1]] if i + 1 < len(ts) else torch.tensor(1.0)
            a_prev = a_prev.to(z.device, torch.float32)
            z = a_prev.sqrt() * pred.x0 + (1.0 - a_prev).sqrt() * pred.eps
        with torch.no_grad():
            return self.decode(z).clamp(0.0, 1.0)
