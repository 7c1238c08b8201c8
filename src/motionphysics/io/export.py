"""Per-frame export of the deformed splats as INRIA 3DGS ``.ply`` files (``splats/``).

Each visible splat follows its parent particle (``SimScene.splat_parent``) the way the
renderer moves it: ``mean_t = x_t[parent] + F_t[parent] @ offset`` and
``cov_t = F Σ Fᵀ``. The deformed covariance is factored back into the INRIA storage
(log scales and a unit wxyz quaternion) by a symmetric eigen-decomposition, so the
files open in standard splat viewers and read back with
:func:`motionphysics.scene.ply.read_ply`. Opacities and SH coefficients are copied
unchanged: the view-dependent (degree >= 1) part is not rotated with the material
(the renderer rotates view directions instead; a file has no such hook).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["deformed_splats", "export_splats", "frame_file_name", "with_static"]


def with_static(splats, sim_scene):
    """``(splats + the static splats of a region run, {"simulated": [N + S] uint8})``, or
    ``(splats, None)`` when the scene has no static splats."""
    static = getattr(sim_scene, "static_splats", None)
    if static is None:
        return splats, None
    from motionphysics.scene.gaussians import GaussianScene

    flag = np.concatenate([np.ones(splats.num, np.uint8), np.zeros(static.num, np.uint8)])
    return GaussianScene.concat([splats, static]), {"simulated": flag}


def frame_file_name(frame: int) -> str:
    """File name of frame ``frame`` inside ``splats/`` (zero-padded, sorts in order)."""
    return f"frame_{frame:04d}.ply"


def deformed_splats(splats, x, F, parent, offset):
    """The splats of one frame as a :class:`~motionphysics.scene.gaussians.GaussianScene`.

    Parameters
    ----------
    splats: GaussianScene with N splats (rest state, world frame).
    x: [P, 3] particle positions [m] at this frame (numpy or torch).
    F: [P, 3, 3] deformation gradients [-] at this frame.
    parent: [N] int index of the particle each splat follows.
    offset: [N, 3] rest offset of the splat mean from its parent [m].
    """
    import torch

    from motionphysics.scene.gaussians import GaussianScene, rotmat_to_quat

    x_t = torch.as_tensor(np.asarray(x), dtype=torch.float64)
    F_t = torch.as_tensor(np.asarray(F), dtype=torch.float64)
    par = torch.as_tensor(np.asarray(parent), dtype=torch.long)
    off = torch.as_tensor(np.asarray(offset), dtype=torch.float64)
    Fp = F_t[par]  # [N, 3, 3]
    means = x_t[par] + (Fp @ off[:, :, None])[:, :, 0]
    cov0 = splats.covariances().to(torch.float64)
    cov = Fp @ cov0 @ Fp.transpose(-1, -2)
    cov = 0.5 * (cov + cov.transpose(-1, -2))
    evals, evecs = torch.linalg.eigh(cov)  # ascending; columns are the axes
    # A proper rotation (det +1) so the quaternion exists.
    sign = torch.where(torch.linalg.det(evecs) < 0, -1.0, 1.0).to(evecs.dtype)
    evecs = (
        evecs * torch.stack([torch.ones_like(sign), torch.ones_like(sign), sign], -1)[:, None, :]
    )
    floor = (1e-8 * evals.abs().amax(-1, keepdim=True)).clamp_min(1e-20)
    log_scales = 0.5 * torch.log(evals.clamp_min(0.0) + floor)
    quats = rotmat_to_quat(evecs)
    dtype = splats.means.dtype
    return GaussianScene(
        means=means.to(dtype),
        log_scales=log_scales.to(dtype),
        quats=quats.to(dtype),
        logit_opacities=splats.logit_opacities.clone(),
        sh=splats.sh.clone(),
    )


def export_splats(
    sim_scene, xs, Fs, out_dir: str | Path, frames: Sequence[int] | None = None, on_frame=None
) -> list[Path]:
    """Write ``frame_XXXX.ply`` for each frame (all by default) into ``out_dir``.

    ``xs`` [T, P, 3] m and ``Fs`` [T, P, 3, 3] are the simulated particle states;
    ``sim_scene`` supplies ``splats``, ``splat_parent`` and ``splat_offset``. With the
    static splats of a ``scene.region`` run (``sim_scene.static_splats``) every file
    holds them after the simulated ones, exactly as in ``scene.ply``, and a per-splat
    ``simulated`` property (uint8, 1 = simulated) says which is which. Each file is
    written atomically. ``on_frame()`` is called after each file (progress).
    """
    from motionphysics.scene.ply import write_ply

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    T = int(np.asarray(xs).shape[0]) if not hasattr(xs, "shape") else int(xs.shape[0])
    paths = []
    for i in range(T) if frames is None else frames:
        scene = deformed_splats(
            sim_scene.splats, xs[i], Fs[i], sim_scene.splat_parent, sim_scene.splat_offset
        )
        scene, extra = with_static(scene, sim_scene)
        paths.append(write_ply(scene, out_dir / frame_file_name(int(i)), extra=extra))
        if on_frame is not None:
            on_frame()
    return paths
