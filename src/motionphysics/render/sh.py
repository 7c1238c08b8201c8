"""Real spherical harmonics of degree 0-3 to RGB, with the 3DGS constants and ordering.

``sh_to_rgb(sh [N, K, 3], dirs [N, 3]) -> [N, 3]`` evaluates
``max(0.5 + sum_k c_k Y_k(d), 0)`` where ``K = (degree + 1)^2`` and ``d`` is the unit
viewing direction (camera centre -> splat centre). Pure torch, differentiable in
``sh`` and ``dirs``; works in any float dtype.
"""

from __future__ import annotations

import torch

__all__ = ["sh_to_rgb", "sh_degree_from_k", "C0"]

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_degree_from_k(k: int) -> int:
    """Degree ``d`` with ``(d + 1)^2 == k``; ValueError for other ``k``."""
    for d in range(4):
        if (d + 1) ** 2 == k:
            return d
    raise ValueError(f"SH coefficient count must be 1, 4, 9 or 16, got {k}")


def sh_to_rgb(sh: torch.Tensor, dirs: torch.Tensor, degree: int | None = None) -> torch.Tensor:
    """RGB ``[N, 3]`` from SH coefficients ``sh [N, K, 3]`` seen along ``dirs [N, 3]``.

    ``dirs`` need not be normalised (zero vectors give the degree-0 colour).
    ``degree`` (default: the full degree of ``K``) may be lower to truncate.
    """
    k = sh.shape[-2]
    full = sh_degree_from_k(k)
    deg = full if degree is None else min(int(degree), full)
    out = C0 * sh[:, 0]
    if deg > 0:
        n = dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        d = dirs / n
        x, y, z = d[:, 0:1], d[:, 1:2], d[:, 2:3]
        out = out - C1 * y * sh[:, 1] + C1 * z * sh[:, 2] - C1 * x * sh[:, 3]
        if deg > 1:
            xx, yy, zz = x * x, y * y, z * z
            xy, yz, xz = x * y, y * z, x * z
            out = (
                out
                + C2[0] * xy * sh[:, 4]
                + C2[1] * yz * sh[:, 5]
                + C2[2] * (2.0 * zz - xx - yy) * sh[:, 6]
                + C2[3] * xz * sh[:, 7]
                + C2[4] * (xx - yy) * sh[:, 8]
            )
            if deg > 2:
                out = (
                    out
                    + C3[0] * y * (3.0 * xx - yy) * sh[:, 9]
                    + C3[1] * xy * z * sh[:, 10]
                    + C3[2] * y * (4.0 * zz - xx - yy) * sh[:, 11]
                    + C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh[:, 12]
                    + C3[4] * x * (4.0 * zz - xx - yy) * sh[:, 13]
                    + C3[5] * z * (xx - yy) * sh[:, 14]
                    + C3[6] * x * (xx - 3.0 * yy) * sh[:, 15]
                )
    return (out + 0.5).clamp_min(0.0)
