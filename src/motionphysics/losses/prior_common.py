"""What the prior-driven losses (``lmd``, ``sds``, ``flow``, ``video``) share: finding the
prior, encoding with the loss's generator, drawing t and the noise, the step weights, and
the once-per-run reference clip (``prior_reference.mp4``).

Random draws come from the loop's generator (``LossContext.rng``), whose state the loop
checkpoints, so a resumed run draws the same t and noise.
"""

from __future__ import annotations

import inspect
from pathlib import Path

import torch
from torch import Tensor

from motionphysics.errors import UserInputError

__all__ = [
    "draw_t_noise",
    "encode",
    "need_frames_prior",
    "need_prior",
    "observe",
    "observes_states",
    "reference_clip",
    "step_weight",
]


def resolve_negative(negative_prompt: str, prompt: str) -> str:
    """A loss's ``negative_prompt`` option as used: ``auto`` becomes the contrasting
    description of :func:`motionphysics.language.captions.contrast_prompt`."""
    if negative_prompt != "auto":
        return negative_prompt
    from motionphysics.language.captions import contrast_prompt

    return contrast_prompt(prompt)


def need_prior(loss: str, prior, prompt: str, negative_prompt: str = ""):
    """The build context's prior, with the prompt (and the prompt guidance is taken
    against) set; a one-line error without one."""
    if prior is None:
        raise UserInputError(
            f"optimize.loss {loss!r} needs a motion prior; set --prior motion|cogvideox|modelscope"
        )
    prior.set_prompt(prompt, negative_prompt)
    return prior


def observes_states(prior) -> bool:
    """True when ``prior`` observes the simulated states (the loop need not render)."""
    return getattr(prior, "observes", "frames") == "states"


def need_frames_prior(loss: str, prior) -> None:
    """A one-line error when a loss that compares pixels is given a prior that sees states."""
    if prior is not None and observes_states(prior):
        raise UserInputError(
            f"optimize.loss {loss!r} compares rendered frames with a clip the prior generates; "
            f"prior {getattr(prior, 'name', '?')!r} observes simulated states, not frames "
            "(use lmd or sds with it, or a frames prior: cogvideox, modelscope)"
        )


def observe(prior, pred, rng: torch.Generator | None, offset: Tensor | None = None) -> Tensor:
    """What ``prior`` observes of the prediction ``pred`` (a ``losses.base.Prediction``),
    encoded to its latents with grad: the rendered frames (``pred.rgb``), or the
    simulated states (``pred.xs``, ``pred.Fs`` at ``pred.frame_indices``) for a prior
    that observes states. ``offset`` [P, 3] m: a geometry perturbation added to every
    observed position and to the rest state (states priors only)."""
    if observes_states(prior):
        if pred.xs is None or pred.Fs is None:
            raise ValueError(f"prior {prior.name} observes simulated states (Prediction.xs, Fs)")
        xs = pred.xs if offset is None else pred.xs + offset.to(pred.xs)
        return prior.encode_states(xs, pred.Fs, tuple(pred.frame_indices), offset=offset)
    if pred.rgb is None:
        raise ValueError("this prior observes rendered frames (Prediction.rgb)")
    return encode(prior, pred.rgb, rng)


def encode(prior, frames: Tensor, rng: torch.Generator | None) -> Tensor:
    """``prior.encode`` with the generator where the backend accepts one."""
    try:
        takes = "generator" in inspect.signature(prior.encode).parameters
    except (TypeError, ValueError):
        takes = False
    return prior.encode(frames, generator=rng) if takes else prior.encode(frames)


def draw_t_noise(
    rng: torch.Generator, shape: tuple[int, ...], t_min: int, t_max: int, device
) -> tuple[Tensor, Tensor]:
    """t ~ U{t_min..t_max} ([1] long) and ε ~ N(0, I) of ``shape``, both from ``rng``."""
    t = torch.randint(t_min, t_max + 1, (1,), generator=rng)
    noise = torch.randn(shape, generator=rng)
    return t.to(device), noise.to(device)


def step_weight(kind: str, alpha_bar: Tensor) -> Tensor:
    """w(t): ``uniform`` 1, ``sds`` 1 − ᾱ_t (DreamFusion / DreamPhysics), ``snr`` √(ᾱ/(1−ᾱ))."""
    if kind == "uniform":
        return torch.ones_like(alpha_bar)
    if kind == "sds":
        return 1.0 - alpha_bar
    if kind == "snr":
        return (alpha_bar / (1.0 - alpha_bar).clamp_min(1e-8)).sqrt()
    raise ValueError(f"unknown weighting {kind!r}")


def check_t_range(loss: str, prior, t_min: int, t_max: int) -> None:
    n = prior.num_train_timesteps
    if not 0 <= t_min <= t_max < n:
        raise UserInputError(
            f"optimize.losses.{loss}: t_min {t_min} / t_max {t_max} must satisfy "
            f"0 <= t_min <= t_max < {n} (the prior's timesteps)"
        )


def reference_clip(
    prior,
    prompt: str,
    *,
    steps: int,
    guidance: float,
    seed: int,
    out_dir: Path | None,
    duration_s: float | None,
) -> Tensor:
    """The prior's clip for ``prompt`` ([num_frames, H, W, 3] in [0, 1], no grad), sampled
    once per run and cached on the prior (``flow`` and ``video`` in one run share it); it
    is written to ``out_dir/prior_reference.mp4`` so a person sees what the prior believes.

    ``duration_s``: the run's simulated duration; the video's frame rate spreads the
    clip's frames over it (8 fps when unknown, CogVideoX's rate)."""
    prior.set_prompt(prompt)
    key = (prompt, int(steps), float(guidance), int(seed))
    cache = getattr(prior, "_reference_cache", None)
    if cache is None:
        cache = {}
        prior._reference_cache = cache
    if key not in cache:
        gen = torch.Generator().manual_seed(int(seed))
        with torch.no_grad():
            cache[key] = prior.sample(steps=steps, guidance=guidance, generator=gen).float().cpu()
    clip = cache[key]
    if out_dir is not None:
        from motionphysics.io.video import write_video

        fps = 8.0
        if duration_s and duration_s > 0:
            fps = max(1.0, clip.shape[0] / duration_s)
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        write_video(clip.numpy(), Path(out_dir) / "prior_reference.mp4", fps=fps)
    return clip
