"""Shared pieces of the prior-loss tests (tests/losses/test_losses_{lmd,sds,flow,video}.py):
tiny priors loaded through the real loader, frames that are a smooth function of one
parameter, the two-iteration end-to-end check and the finite-difference check."""

from __future__ import annotations

from pathlib import Path

import torch

from motionphysics.losses import LOSSES, LossBuildContext, LossContext, Prediction

_PRIORS: dict = {}


def tiny_prior(kind: str, **options):
    """A tiny prior (cached per process): ``cogvideox`` / ``modelscope`` / ``analytic``."""
    key = (kind, tuple(sorted(options.items())))
    if key not in _PRIORS:
        if kind == "analytic":
            from analytic_prior import AnalyticPrior

            _PRIORS[key] = AnalyticPrior(**options)
        else:
            from tiny_pipelines import load_tiny

            _PRIORS[key] = load_tiny(kind, **options)
    return _PRIORS[key]


def moving_edge(theta: torch.Tensor, frames: int = 6, size: int = 16, dtype=torch.float32):
    """[frames, size, size, 3] in (0, 1): a soft vertical edge whose speed is ``theta``
    (a tiny differentiable stand-in for simulate + render), coloured per channel."""
    lin = torch.linspace(0, 1, size, dtype=dtype)
    ys, xs = torch.meshgrid(lin, lin, indexing="ij")
    out = []
    for k in range(frames):
        edge = torch.sigmoid(12 * (xs - 0.25 - theta * k / frames + 0.1 * ys))
        out.append(torch.stack([edge, 0.5 * edge + 0.2, 1 - 0.8 * edge], dim=-1))
    return torch.stack(out)


def build(name: str, prior, out_dir: Path | None = None, seed: int = 0, **options):
    opts = LOSSES.options(name, options)
    ctx = LossBuildContext(
        prompt="a rubber ball bounces on the floor",
        prior=prior,
        num_frames=24,
        frame_dt=1 / 24,
        out_dir=out_dir,
        device="cpu",
        seed=seed,
    )
    return LOSSES.get(name).build(opts, ctx)


def two_iterations_move_theta(loss, frames: int = 6, lr: float = 0.05):
    """Two iterations of theta ← theta − lr·dL/dθ; returns (values, grads, theta)."""
    theta = torch.tensor(0.4, requires_grad=True)
    rng = torch.Generator().manual_seed(0)
    values, grads = [], []
    for it in range(2):
        rgb = moving_edge(theta, frames)
        pred = Prediction(frame_indices=tuple(range(frames)), rgb=rgb)
        value = loss(pred, LossContext(iteration=it, num_frames=24, rng=rng))
        (g,) = torch.autograd.grad(value, theta)
        values.append(float(value.detach()))
        grads.append(float(g))
        with torch.no_grad():
            theta -= lr * g / max(abs(float(g)), 1e-12)  # a normalised step: moves when g != 0
    return values, grads, float(theta)


def call(loss, rgb, seed=5):
    """One evaluation with a freshly seeded generator (same t, noise, posterior draw)."""
    pred = Prediction(frame_indices=tuple(range(rgb.shape[0])), rgb=rgb)
    return loss(
        pred, LossContext(iteration=0, num_frames=24, rng=torch.Generator().manual_seed(seed))
    )


def fd_check_pixel(evaluate, rgb: torch.Tensor, h: float = 1e-6, rtol: float = 1e-4):
    """Central differences of ``evaluate(rgb)`` at the pixel of largest |autograd grad|
    (and one more), against autograd. ``rgb`` float64."""
    x = rgb.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(evaluate(x), x)
    assert torch.isfinite(g).all() and g.abs().max() > 0
    flat = g.abs().flatten()
    picks = [int(flat.argmax()), int(flat.argsort()[len(flat) * 3 // 4])]
    for idx in picks:
        e = torch.zeros_like(rgb).flatten()
        e[idx] = h
        e = e.view_as(rgb)
        with torch.no_grad():
            fd = (float(evaluate(rgb + e)) - float(evaluate(rgb - e))) / (2 * h)
        ad = float(g.flatten()[idx])
        assert abs(fd - ad) <= rtol * abs(ad) + 1e-9 * float(flat.max()) + 1e-12, (idx, fd, ad)
