"""Differentiable tile-based splat rasteriser (3DGS image formation), with backends.

``rasterize(means, covs, colors, opacities, camera, background)`` renders RGB, alpha
and depth by front-to-back alpha compositing of EWA-projected Gaussians, and is
differentiable w.r.t. ``means``, ``covs``, ``colors`` and ``opacities``.

Image formation (identical in every CPU path and in the dense reference twin):

* projection (:func:`project_gaussians`): camera-space centre ``t``; the EWA Jacobian
  ``J`` of the pinhole map at ``t`` (with 3DGS's clamp of ``t_x / t_z`` to 1.3 tan of the
  half field of view); 2D covariance ``J W Σ Wᵀ Jᵀ + 0.3 I`` (the 0.3 px² low-pass
  dilation of 3DGS); conic = its inverse. Splats with ``t_z <= near`` are culled.
* per pixel (centre at ``(i + 0.5, j + 0.5)``), splats sorted by depth ``t_z``:
  ``a = min(0.99, o exp(-q / 2))`` with ``q`` the conic's Mahalanobis distance, then
  the 3DGS cut ``a < 1/255`` made smooth: ``a' = a * s((a - τ) / τ)``, ``τ = 1/255``,
  ``s`` the C1 smoothstep clipped to [0, 1]. So a splat's weight fades to zero with
  zero slope where 3DGS would drop it, and moving a splat never makes the image jump
  (the hard cut biases finite-difference vs autograd comparisons; see BENCHMARKS.md).
  Tile membership uses the exact bounding box of the ellipse ``a >= τ``
  (``q <= 2 ln(255 o)``), so it never cuts a non-zero weight.
* ``C = Σ_i c_i a'_i T_i + T_final * background`` with ``T_i = Π_{j<i} (1 - a'_j)``;
  compositing stops (3DGS) before the splat that would bring ``T`` below 1e-4 (a jump
  of at most 1e-4 in the image). ``alpha = 1 - T_final``; ``depth = Σ z_i w_i / Σ w_i``
  with ``w_i = a'_i T_i`` (expected depth of what is seen [m], 0 where nothing is).

Backends: ``torch`` (CPU or any device; pure PyTorch, tiles batched and padded),
``warp`` (CPU, compiled Warp kernels with a hand-written backward: the fast CPU
path), ``gsplat`` (CUDA; the gsplat package's ``rasterization``, hard 1/255 cut).
``auto`` picks gsplat on CUDA tensors and warp on CPU.
"""

from __future__ import annotations

import math

import torch

from motionphysics.errors import UserInputError
from motionphysics.render.camera import Camera
from motionphysics.render.core import (
    ALPHA_MAX,
    ALPHA_MIN,
    EPS2D,
    NEAR,
    RENDER_BACKENDS,
    T_MIN,
    TILE,
    WARP_TILE,
    Projected,
    RenderOutput,
    TileBins,
    project_gaussians,
)
from motionphysics.render.core import features as _features
from motionphysics.render.core import finish as _finish

__all__ = [
    "EPS2D",
    "NEAR",
    "TileBins",
    "RenderOutput",
    "Projected",
    "project_gaussians",
    "rasterize",
    "rasterize_reference",
    "BACKENDS",
    "TILE",
    "ALPHA_MIN",
    "T_MIN",
]

BACKENDS = tuple(RENDER_BACKENDS.names())


def _taper_alpha(alpha: torch.Tensor) -> torch.Tensor:
    """The smooth version of 3DGS's ``alpha < 1/255`` cut (module docstring)."""
    s = ((alpha - ALPHA_MIN) / ALPHA_MIN).clamp(0.0, 1.0)
    return alpha * (s * s * (3.0 - 2.0 * s))


def _alpha(means2d, conics, opacities, px, py, cut: str = "smooth"):
    """Alphas for pixel centres ``px, py`` (broadcast against splat tensors).

    ``cut="smooth"`` is this renderer's C1 taper; ``"hard"`` is 3DGS's ``a < 1/255 -> 0``
    (kept for the gradient-bias measurement only).
    """
    dx = means2d[..., 0] - px
    dy = means2d[..., 1] - py
    power = -0.5 * (conics[..., 0] * dx * dx + conics[..., 2] * dy * dy) - conics[..., 1] * dx * dy
    alpha = (opacities * torch.exp(power.clamp(max=0.0))).clamp(max=ALPHA_MAX)
    if cut == "hard":
        return torch.where(alpha < ALPHA_MIN, torch.zeros_like(alpha), alpha)
    return _taper_alpha(alpha)


def _composite(alpha: torch.Tensor, feats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Front-to-back compositing along the last splat axis.

    alpha ``[..., L]`` (depth-sorted), feats ``[..., L, C]`` -> (accumulated features
    ``[..., C]``, final transmittance ``[...]``), applying the 1e-4 stop.
    """
    one_minus = 1.0 - alpha
    t_incl = torch.cumprod(one_minus, dim=-1)
    keep = (t_incl >= T_MIN).to(alpha.dtype).detach()  # a prefix: T is non-increasing
    alpha = alpha * keep
    t_incl = torch.cumprod(1.0 - alpha, dim=-1)
    t_excl = torch.cat([torch.ones_like(t_incl[..., :1]), t_incl[..., :-1]], dim=-1)
    w = alpha * t_excl
    acc = (w.unsqueeze(-1) * feats).sum(-2)
    return acc, t_incl[..., -1]


def rasterize_reference(
    means, covs, colors, opacities, camera: Camera, background, cut: str = "smooth"
) -> RenderOutput:
    """Dense reference twin: every pixel against every splat (use float64, tiny scenes).

    Same image formation as :func:`rasterize`, no tiles, no culling beyond the near
    plane and the zero-weight box. Memory ``H * W * N``; for tests and measurements.
    ``cut="hard"`` swaps in 3DGS's discontinuous 1/255 cut.
    """
    proj = project_gaussians(means, covs, opacities, camera)
    order = torch.argsort(proj.depths.detach())
    keep = order[(proj.extents[order, 0] > 0)]
    H, W = camera.height, camera.width
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=means.dtype) + 0.5,
        torch.arange(W, dtype=means.dtype) + 0.5,
        indexing="ij",
    )
    px, py = xs.reshape(-1, 1), ys.reshape(-1, 1)  # [HW, 1]
    alpha = _alpha(proj.means2d[keep], proj.conics[keep], opacities[keep], px, py, cut)  # [HW, n]
    feats = _features(colors, proj.depths)[keep]  # [n, 5]
    acc, t_final = _composite(alpha, feats.expand(alpha.shape[0], -1, -1))
    return _finish(acc.reshape(H, W, -1), t_final.reshape(H, W), background)


def bin_tiles(proj: Projected, width: int, height: int, tile: int = TILE) -> TileBins:
    """Sort splats by depth and list, per tile, those whose box touches it."""
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    n_tiles = tiles_x * tiles_y
    dev = proj.means2d.device
    with torch.no_grad():
        ext = proj.extents
        idx = torch.nonzero(ext[:, 0] > 0).squeeze(1)
        idx = idx[torch.argsort(proj.depths[idx], stable=True)]
        m2 = proj.means2d[idx]
        e = ext[idx]
        x0 = ((m2[:, 0] - e[:, 0]) / tile).floor().clamp(0, tiles_x - 1).long()
        x1 = ((m2[:, 0] + e[:, 0]) / tile).floor().clamp(0, tiles_x - 1).long()
        y0 = ((m2[:, 1] - e[:, 1]) / tile).floor().clamp(0, tiles_y - 1).long()
        y1 = ((m2[:, 1] + e[:, 1]) / tile).floor().clamp(0, tiles_y - 1).long()
        nx, ny = x1 - x0 + 1, y1 - y0 + 1
        counts = nx * ny
        total = int(counts.sum())
        if total == 0:
            return TileBins(
                torch.zeros(0, dtype=torch.long, device=dev),
                torch.zeros(n_tiles + 1, dtype=torch.long, device=dev),
                tiles_x,
                tiles_y,
                tile,
            )
        owner = torch.repeat_interleave(torch.arange(idx.numel(), device=dev), counts)  # [total]
        start = torch.cumsum(counts, 0) - counts
        local = torch.arange(total, device=dev) - start[owner]
        tx = x0[owner] + local % nx[owner]
        ty = y0[owner] + local // nx[owner]
        tile_id = ty * tiles_x + tx
        # Entries are generated front to back; a stable sort by tile keeps that order.
        perm = torch.argsort(tile_id, stable=True)
        ids = idx[owner[perm]]
        counts_t = torch.bincount(tile_id, minlength=n_tiles)
        offsets = torch.zeros(n_tiles + 1, dtype=torch.long, device=dev)
        offsets[1:] = torch.cumsum(counts_t, 0)
    return TileBins(ids, offsets, tiles_x, tiles_y, tile)


def _raster_torch(
    proj: Projected,
    feats: torch.Tensor,
    opacities: torch.Tensor,
    bins: TileBins,
    width: int,
    height: int,
    tile: int = TILE,
    budget: int = 1 << 21,
):
    """Pure-PyTorch tile compositing; returns (acc ``[H, W, C]``, T ``[H, W]``).

    Tiles are processed in batches padded to the batch's longest list so one batch
    holds about ``budget`` pixel-splat pairs (large temporaries page-fault on CPU).
    """
    dtype, device = feats.dtype, feats.device
    C = feats.shape[1]
    n_tiles = bins.tiles_x * bins.tiles_y
    lengths = bins.offsets[1:] - bins.offsets[:-1]
    acc_tiles = torch.zeros(n_tiles, tile * tile, C, dtype=dtype, device=device)
    t_tiles = torch.ones(n_tiles, tile * tile, dtype=dtype, device=device)
    ly, lx = torch.meshgrid(
        torch.arange(tile, device=device), torch.arange(tile, device=device), indexing="ij"
    )
    ly, lx = ly.reshape(-1), lx.reshape(-1)
    active = torch.nonzero(lengths > 0).squeeze(1)
    # Group tiles of similar length together so padding stays small.
    active = active[torch.argsort(lengths[active])]
    acc_list, t_list, tile_list = [], [], []
    i = 0
    while i < active.numel():
        L = int(lengths[active[i]])
        # grow the batch while the padded size fits the budget
        j = i + 1
        while j < active.numel() and (j + 1 - i) * tile * tile * int(lengths[active[j]]) <= budget:
            j += 1
        batch = active[i:j]
        L = int(lengths[batch].max())
        ar = torch.arange(L, device=device)
        pos = bins.offsets[batch, None] + ar  # [B, L]
        valid = ar[None, :] < lengths[batch, None]
        sid = bins.ids[pos.clamp(max=max(bins.ids.numel() - 1, 0))]  # [B, L]
        tx = (batch % bins.tiles_x) * tile
        ty = (batch // bins.tiles_x) * tile
        px = (tx[:, None] + lx[None, :]).to(dtype) + 0.5  # [B, P]
        py = (ty[:, None] + ly[None, :]).to(dtype) + 0.5
        m2 = proj.means2d[sid]  # [B, L, 2]
        con = proj.conics[sid]
        op = opacities[sid] * valid.to(dtype)
        alpha = _alpha(
            m2[:, None], con[:, None], op[:, None], px[..., None], py[..., None]
        )  # [B,P,L]
        acc, t_final = _composite(alpha, feats[sid][:, None].expand(-1, tile * tile, -1, -1))
        acc_list.append(acc)
        t_list.append(t_final)
        tile_list.append(batch)
        i = j
    if tile_list:
        all_tiles = torch.cat(tile_list)
        acc_tiles = acc_tiles.index_copy(0, all_tiles, torch.cat(acc_list))
        t_tiles = t_tiles.index_copy(0, all_tiles, torch.cat(t_list))
    acc = acc_tiles.reshape(bins.tiles_y, bins.tiles_x, tile, tile, C).permute(0, 2, 1, 3, 4)
    acc = acc.reshape(bins.tiles_y * tile, bins.tiles_x * tile, C)[:height, :width]
    tt = t_tiles.reshape(bins.tiles_y, bins.tiles_x, tile, tile).permute(0, 2, 1, 3)
    tt = tt.reshape(bins.tiles_y * tile, bins.tiles_x * tile)[:height, :width]
    return acc, tt


def _check_inputs(means, covs, colors, opacities, camera, background) -> None:
    n = means.shape[0] if means.ndim == 2 else -1
    if means.ndim != 2 or means.shape[1] != 3:
        raise UserInputError(f"rasterize: means must be [N, 3], got {tuple(means.shape)}")
    if tuple(covs.shape) != (n, 3, 3):
        raise UserInputError(f"rasterize: covs must be [{n}, 3, 3], got {tuple(covs.shape)}")
    if tuple(colors.shape) != (n, 3):
        raise UserInputError(f"rasterize: colors must be [{n}, 3], got {tuple(colors.shape)}")
    if tuple(opacities.shape) != (n,):
        raise UserInputError(f"rasterize: opacities must be [{n}], got {tuple(opacities.shape)}")
    if torch.as_tensor(background).numel() != 3:
        raise UserInputError("rasterize: background must be 3 numbers (RGB in [0, 1])")
    if not isinstance(camera, Camera):
        raise UserInputError(f"rasterize: camera must be a Camera, got {type(camera).__name__}")


def resolve_backend(backend: str, device: torch.device) -> str:
    """The concrete backend for ``backend`` on tensors living on ``device``."""
    if backend not in BACKENDS:
        raise UserInputError(
            f"render backend: expected one of {', '.join(BACKENDS)}, got {backend!r}"
        )
    if backend == "auto":
        return "gsplat" if device.type == "cuda" else "warp"
    if backend == "gsplat":
        from motionphysics.render import gsplat_backend

        gsplat_backend.check_available(device)
    if backend == "warp" and device.type != "cpu":
        raise UserInputError(
            "render backend 'warp' runs on CPU tensors; use 'gsplat' or 'torch' on CUDA"
        )
    return backend


def rasterize(
    means: torch.Tensor,
    covs: torch.Tensor,
    colors: torch.Tensor,
    opacities: torch.Tensor,
    camera: Camera,
    background=(1.0, 1.0, 1.0),
    backend: str = "auto",
) -> RenderOutput:
    """Render splats; differentiable in ``means``, ``covs``, ``colors``, ``opacities``.

    Args:
        means: ``[N, 3]`` world centres [m].
        covs: ``[N, 3, 3]`` world covariances [m²] (symmetric positive definite).
        colors: ``[N, 3]`` RGB (typically in [0, 1]).
        opacities: ``[N]`` in [0, 1].
        camera: the view (:class:`~motionphysics.render.camera.Camera`).
        background: RGB ``[3]`` seen where transmittance remains.
        backend: ``auto`` | ``torch`` | ``warp`` | ``gsplat`` (module docstring).
    """
    _check_inputs(means, covs, colors, opacities, camera, background)
    name = resolve_backend(backend, means.device)
    if name == "gsplat":
        from motionphysics.render import gsplat_backend

        return gsplat_backend.rasterize_gsplat(means, covs, colors, opacities, camera, background)
    if name == "warp":
        from motionphysics.render import warp_backend

        rgb, alpha, depth = warp_backend.rasterize_warp(
            means, covs, colors, opacities, camera, background, WARP_TILE
        )
        return RenderOutput(rgb, alpha, depth)
    proj = project_gaussians(means, covs, opacities, camera)
    bins = bin_tiles(proj, camera.width, camera.height, TILE)
    feats = _features(colors, proj.depths)  # [N, 5]
    acc, t_final = _raster_torch(proj, feats, opacities, bins, camera.width, camera.height, TILE)
    return _finish(acc, t_final, background)
