"""gsplat backend: the CUDA rasteriser of the ``gsplat`` package behind :func:`rasterize`.

Written against gsplat's documented ``gsplat.rasterization`` API (covariances passed as
``covars`` with ``quats``/``scales`` None, ``render_mode="RGB+ED"``, classic mode with
``eps2d=0.3``). Differences from the CPU paths: gsplat's hard 1/255 alpha cut and its
3-sigma tile extent (the CPU paths use a smooth cut); colours and expected depth are
otherwise the same image formation. Imported only when a CUDA render is requested.
"""

from __future__ import annotations

import torch

from motionphysics.errors import UserInputError


def check_available(device: torch.device) -> None:
    """Raise one clear UserInputError unless gsplat can run on ``device``."""
    if device.type != "cuda" or not torch.cuda.is_available():
        raise UserInputError(
            "render backend 'gsplat' needs CUDA tensors on a machine with a CUDA device; "
            "use backend 'warp' or 'torch' on CPU"
        )
    try:
        import gsplat  # noqa: F401
    except ImportError:
        raise UserInputError(
            "render backend 'gsplat' needs the gsplat package (pip install gsplat); "
            "or use backend 'torch'"
        ) from None


def rasterize_gsplat(means, covs, colors, opacities, camera, background):
    """Render through ``gsplat.rasterization``; returns a RenderOutput (``[H, W, ...]``)."""
    from gsplat import rasterization

    from motionphysics.render.core import NEAR, RenderOutput

    dev, dtype = means.device, means.dtype
    f32 = torch.float32  # gsplat's kernels are float32 only; cast back at the end
    viewmat = camera.world_to_cam.to(device=dev, dtype=f32)[None]  # [1, 4, 4]
    K = camera.K.to(device=dev, dtype=f32)[None]  # [1, 3, 3]
    bg = torch.as_tensor(background, device=dev, dtype=f32).reshape(1, 3)
    render, alphas, _meta = rasterization(
        means=means.to(f32),
        quats=None,
        scales=None,
        opacities=opacities.to(f32),
        colors=colors.to(f32),
        viewmats=viewmat,
        Ks=K,
        width=camera.width,
        height=camera.height,
        near_plane=NEAR,
        eps2d=0.3,
        packed=False,
        backgrounds=bg,  # gsplat pads the depth channel itself
        render_mode="RGB+ED",
        rasterize_mode="classic",
        covars=covs.to(f32),
    )
    render, alphas = render.to(dtype), alphas.to(dtype)
    return RenderOutput(render[0, ..., :3], alphas[0, ..., 0], render[0, ..., 3])
