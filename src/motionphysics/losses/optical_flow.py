"""Optical flow between frame pairs, differentiable in torch.

- :func:`horn_schunck` (the default; needs no weights): coarse-to-fine Horn–Schunck
  (1981) with warping. Each pyramid level warps the second image by the current flow
  (bilinear ``grid_sample``), linearises brightness constancy around it and runs a fixed
  number of Jacobi iterations of the Horn–Schunck update
  ``u ← ū − I_x (I_x ū' + I_y v̄' + I_t') / (α² + I_x² + I_y²)``. Every step is a torch op,
  so gradients flow to both images.
- :class:`RaftFlow`: torchvision's RAFT-large from a local weights file (PhysFlow's
  estimator), only where torchvision is importable; selected explicitly.

Flow is ``[N, 2, H, W]`` in pixels, (u, v) = (x, y): ``b(p + flow(p)) ≈ a(p)``.
Images are ``[N, H, W, 3]`` in [0, 1]. This module must not know about priors.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from motionphysics.errors import UserInputError

__all__ = ["RaftFlow", "horn_schunck", "warp"]

_AVG = torch.tensor([[1 / 12, 1 / 6, 1 / 12], [1 / 6, 0.0, 1 / 6], [1 / 12, 1 / 6, 1 / 12]])


def _gray(x: Tensor) -> Tensor:
    """[N, H, W, 3] -> [N, 1, H, W] luma (Rec. 601)."""
    w = torch.tensor([0.299, 0.587, 0.114], dtype=x.dtype, device=x.device)
    return (x * w).sum(-1).unsqueeze(1)


def _blur(x: Tensor, sigma: float) -> Tensor:
    if sigma <= 0:
        return x
    r = max(1, int(round(2 * sigma)))
    k = torch.exp(-(torch.arange(-r, r + 1, dtype=x.dtype, device=x.device) ** 2) / (2 * sigma**2))
    k = k / k.sum()
    x = F.conv2d(F.pad(x, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1))
    return F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1))


def warp(img: Tensor, flow: Tensor) -> Tensor:
    """Sample ``img [N, C, H, W]`` at ``p + flow(p)`` (bilinear, border-clamped)."""
    n, _, h, w = img.shape
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=img.dtype, device=img.device),
        torch.arange(w, dtype=img.dtype, device=img.device),
        indexing="ij",
    )
    gx = (xs + flow[:, 0]) * (2.0 / max(w - 1, 1)) - 1.0
    gy = (ys + flow[:, 1]) * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1)  # [N, H, W, 2]
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def _grad_xy(x: Tensor) -> tuple[Tensor, Tensor]:
    """Central differences with replicated borders, [N, 1, H, W] each."""
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    gx = 0.5 * (p[..., 1:-1, 2:] - p[..., 1:-1, :-2])
    gy = 0.5 * (p[..., 2:, 1:-1] - p[..., :-2, 1:-1])
    return gx, gy


def horn_schunck(
    a: Tensor,
    b: Tensor,
    *,
    alpha: float = 0.05,
    iterations: int = 40,
    levels: int | None = None,
    sigma: float = 1.0,
) -> Tensor:
    """Flow from ``a`` to ``b`` ([N, H, W, 3] in [0, 1]) -> [N, 2, H, W] pixels.

    ``alpha``: smoothness weight (on [0, 1] intensities); ``iterations``: Jacobi
    iterations per level; ``levels``: pyramid levels (None: halve until the short side
    is under 16 px); ``sigma``: Gaussian pre-smoothing in pixels."""
    ga, gb = _blur(_gray(a), sigma), _blur(_gray(b), sigma)
    if levels is None:
        levels, side = 1, min(ga.shape[-2:])
        while side >= 32:
            side //= 2
            levels += 1
    pyr = [(ga, gb)]
    for _ in range(levels - 1):
        pa, pb = pyr[-1]
        pyr.append((F.avg_pool2d(pa, 2, ceil_mode=True), F.avg_pool2d(pb, 2, ceil_mode=True)))
    avg = _AVG.to(ga.dtype).to(ga.device).view(1, 1, 3, 3)
    flow = None
    for la, lb in reversed(pyr):
        n, _, h, w = la.shape
        if flow is None:
            flow = la.new_zeros(n, 2, h, w)
        else:
            sh, sw = h / flow.shape[-2], w / flow.shape[-1]
            flow = F.interpolate(flow, size=(h, w), mode="bilinear", align_corners=False)
            flow = torch.cat([flow[:, :1] * sw, flow[:, 1:] * sh], dim=1)
        bw = warp(lb, flow)
        ix, iy = _grad_xy(0.5 * (la + bw))
        it = bw - la
        denom = alpha * alpha + ix * ix + iy * iy
        u0, v0 = flow[:, :1], flow[:, 1:]
        u, v = u0, v0
        for _ in range(iterations):
            ub = F.conv2d(F.pad(u, (1, 1, 1, 1), mode="replicate"), avg)
            vb = F.conv2d(F.pad(v, (1, 1, 1, 1), mode="replicate"), avg)
            r = it + ix * (ub - u0) + iy * (vb - v0)
            u = ub - ix * r / denom
            v = vb - iy * r / denom
        flow = torch.cat([u, v], dim=1)
    return flow


class RaftFlow:
    """torchvision RAFT-large with weights from a local file (no download).

    Frames are mapped to [−1, 1] (PhysFlow) and sized to multiples of 8; the last
    refinement's flow is returned, resized back to the input size."""

    def __init__(self, weights: str | Path | None, device: torch.device | str = "cpu"):
        try:
            from torchvision.models.optical_flow import raft_large
        except ImportError:
            raise UserInputError(
                "optimize.losses.flow.estimator: 'raft' needs torchvision, which is not "
                "installed; use estimator: horn_schunck (no weights needed)"
            ) from None
        if weights is None or not Path(weights).is_file():
            raise UserInputError(
                f"optimize.losses.flow.raft_weights: {weights!r} is not a file; pass the path "
                "of torchvision's raft_large state dict (Raft_Large_Weights)"
            )
        model = raft_large(weights=None, progress=False)
        try:
            model.load_state_dict(torch.load(weights, map_location="cpu", weights_only=True))
        except Exception as err:
            raise UserInputError(
                f"optimize.losses.flow.raft_weights: {weights}: not a raft_large state dict ({err})"
            ) from None
        self.model = model.to(device).eval().requires_grad_(False)

    def __call__(self, a: Tensor, b: Tensor) -> Tensor:
        n, h, w, _ = a.shape
        h8, w8 = (h + 7) // 8 * 8, (w + 7) // 8 * 8
        x = F.interpolate(a.permute(0, 3, 1, 2) * 2 - 1, size=(h8, w8), mode="bilinear")
        y = F.interpolate(b.permute(0, 3, 1, 2) * 2 - 1, size=(h8, w8), mode="bilinear")
        flow = self.model(x, y)[-1]
        flow = F.interpolate(flow, size=(h, w), mode="bilinear")
        return torch.cat([flow[:, :1] * (w / w8), flow[:, 1:] * (h / h8)], dim=1)
