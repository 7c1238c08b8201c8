"""What every rasteriser backend shares: constants of the image formation, the EWA
projection, the composited feature layout, and the output types.

A leaf module: the torch rasteriser (:mod:`.rasterize`) and the Warp and gsplat
backends import from here and never from each other, so adding a backend touches this
module only to read it. The image formation itself is documented in :mod:`.rasterize`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from motionphysics.registry import Registry
from motionphysics.render.camera import Camera

__all__ = [
    "RENDER_BACKENDS",
    "ALPHA_MAX",
    "ALPHA_MIN",
    "EPS2D",
    "NEAR",
    "TILE",
    "T_MIN",
    "WARP_TILE",
    "Projected",
    "RenderOutput",
    "TileBins",
    "features",
    "finish",
    "project_gaussians",
]

RENDER_BACKENDS: Registry = Registry(
    "render backend",
    "--backend",
    {
        # ``auto`` picks gsplat on CUDA tensors and warp on CPU (rasterize.resolve_backend)
        "auto": "motionphysics.render.rasterize:rasterize",
        "torch": "motionphysics.render.rasterize:rasterize",
        "warp": "motionphysics.render.warp_backend:rasterize_warp",
        "gsplat": "motionphysics.render.gsplat_backend:rasterize_gsplat",
    },
)
"""Rasteriser backends by name (the ``--backend`` choices; ``rasterize(backend=...)``)."""

TILE = 16  # tile edge [pixels] of the torch backend
WARP_TILE = 4  # tile edge of the warp backend (per-pixel loops: small tiles, short lists; measured 4 <= 8 < 16)
ALPHA_MIN = 1.0 / 255.0  # 3DGS's cut; here the start of the smooth taper
ALPHA_MAX = 0.99
T_MIN = 1e-4  # compositing stops before transmittance would fall below this
EPS2D = 0.3  # low-pass dilation [px^2]
NEAR = 0.01  # near plane [m]


@dataclass
class RenderOutput:
    """A rendered image.

    rgb: ``[H, W, 3]`` in [0, 1]-ish (colours are not clamped); alpha: ``[H, W]``
    accumulated opacity; depth: ``[H, W]`` expected depth along the camera z [m],
    0 where alpha is 0. Same dtype and device as the inputs.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor


@dataclass
class Projected:
    """Screen-space Gaussians (all ``[N, ...]``, input dtype).

    means2d ``[N, 2]`` px; conics ``[N, 3]`` (a, b, c) of the inverse 2D covariance
    [px^-2]; depths ``[N]`` camera z [m]; extents ``[N, 2]`` half-widths [px] of the
    exact bounding box of the ellipse holding all pixels with alpha >= 1/255 (0 for
    culled splats, detached).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    extents: torch.Tensor


def project_gaussians(
    means: torch.Tensor,
    covs: torch.Tensor,
    opacities: torch.Tensor,
    camera: Camera,
    near: float = NEAR,
) -> Projected:
    """EWA projection of ``means [N, 3]`` (m), ``covs [N, 3, 3]`` (m²) to screen space."""
    R = camera.rotation.to(means)
    t = camera.translation.to(means)
    pc = means @ R.T + t  # [N, 3] camera space
    z = pc[:, 2]
    valid = z > near
    zs = torch.where(valid, z, torch.ones_like(z))  # keeps culled splats finite
    tan_x = 0.5 * camera.width / camera.fx
    tan_y = 0.5 * camera.height / camera.fy
    lim_x, lim_y = 1.3 * tan_x, 1.3 * tan_y
    tx = (pc[:, 0] / zs).clamp(-lim_x, lim_x) * zs
    ty = (pc[:, 1] / zs).clamp(-lim_y, lim_y) * zs
    zero = torch.zeros_like(zs)
    J = torch.stack(
        [
            torch.stack([camera.fx / zs, zero, -camera.fx * tx / zs**2], -1),
            torch.stack([zero, camera.fy / zs, -camera.fy * ty / zs**2], -1),
        ],
        -2,
    )  # [N, 2, 3]
    M = J @ R  # [N, 2, 3]
    cov2 = M @ covs @ M.transpose(1, 2)  # [N, 2, 2]
    a = cov2[:, 0, 0] + EPS2D
    b = 0.5 * (cov2[:, 0, 1] + cov2[:, 1, 0])
    c = cov2[:, 1, 1] + EPS2D
    det = a * c - b * b
    det_s = torch.where(valid & (det > 0), det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], -1)
    u = camera.fx * pc[:, 0] / zs + camera.cx
    v = camera.fy * pc[:, 1] / zs + camera.cy
    means2d = torch.stack([u, v], -1)
    with torch.no_grad():
        # o exp(-q/2) >= 1/255  <=>  q <= q_max; the ellipse q <= q_max of the 2D
        # covariance [[a, b], [b, c]] has the bounding box +-sqrt(q_max a), +-sqrt(q_max c).
        # (o, not min(o, 0.99): the clamp never binds near the 1/255 boundary)
        q_max = 2.0 * torch.log((opacities.detach() / ALPHA_MIN).clamp_min(1.0))
        extents = torch.sqrt(torch.stack([q_max * a, q_max * c], -1).clamp_min(0.0))
        ok = valid & (det > 0) & (q_max > 0) & torch.isfinite(extents).all(-1)
        ok &= (u + extents[:, 0] > 0) & (u - extents[:, 0] < camera.width)
        ok &= (v + extents[:, 1] > 0) & (v - extents[:, 1] < camera.height)
        extents = torch.where(ok[:, None], extents, torch.zeros_like(extents))
    return Projected(means2d, conics, z, extents)


def features(colors: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """Channels composited per splat ``[N, 5]``: r, g, b, depth, 1.

    The last channel accumulates ``Σ w_i`` (= alpha) without the cancellation of
    ``1 - T`` in float32, for the depth normalisation.
    """
    return torch.cat([colors, depths[:, None], torch.ones_like(depths[:, None])], -1)


def finish(acc: torch.Tensor, t_final: torch.Tensor, background) -> RenderOutput:
    """Accumulated ``[H, W, 5]`` (rgb, depth·w, w) and ``T [H, W]`` -> RenderOutput."""
    bg = torch.as_tensor(background, dtype=acc.dtype, device=acc.device).reshape(3)
    alpha = 1.0 - t_final
    rgb = acc[..., :3] + t_final[..., None] * bg
    wsum = acc[..., 4]
    depth = torch.where(wsum > 0, acc[..., 3] / wsum.clamp_min(1e-30), torch.zeros_like(wsum))
    return RenderOutput(rgb, alpha, depth)


@dataclass
class TileBins:
    """Per-tile depth-ordered splat lists (CSR layout).

    ids ``[M] long`` splat indices; offsets ``[n_tiles + 1] long`` (tile ``k``'s list
    is ``ids[offsets[k]:offsets[k + 1]]``, front to back); tiles_x, tiles_y counts.
    """

    ids: torch.Tensor
    offsets: torch.Tensor
    tiles_x: int
    tiles_y: int
    tile: int = TILE
