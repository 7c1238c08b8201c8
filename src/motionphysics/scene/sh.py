"""Real spherical harmonics in the 3DGS convention, and their rotation.

``sh_basis`` is exactly the basis of the reference 3DGS ``eval_sh`` (same constants,
same signs, same order), so coefficients read from an INRIA ply mean the same here.
Colour seen along unit direction d (from the camera to the splat) is
``0.5 + sum_k sh[k] * B_k(d)`` (clamped at 0 by renderers).

Rotating a splat by R must keep its appearance attached to it: the new coefficients
``sh'`` satisfy ``f'(R d) = f(d)`` for every d. Each band l is closed under rotation,
so per band ``B_l(R^T d) = B_l(d) A_l`` for a (2l+1)x(2l+1) matrix ``A_l`` and
``sh'_l = A_l sh_l``. ``A_l`` is recovered exactly (to float precision) from a fixed set
of directions D with the precomputed pseudo-inverse of ``B_l(D)``: this is
differentiable in R and batched over any number of rotations.
"""

from __future__ import annotations

import math
from functools import cache

import torch

__all__ = ["sh_basis", "eval_sh", "rotate_sh", "sh_band_rotations"]

_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """3DGS real SH basis at unit directions ``dirs [..., 3]`` -> ``[..., (degree+1)^2]``."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, _C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            _C2[0] * xy,
            _C2[1] * yz,
            _C2[2] * (2 * zz - xx - yy),
            _C2[3] * xz,
            _C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            _C3[0] * y * (3 * xx - yy),
            _C3[1] * xy * z,
            _C3[2] * y * (4 * zz - xx - yy),
            _C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            _C3[4] * x * (4 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Colour before the +0.5 offset: ``sh [N, K, 3]``, unit ``dirs [N, 3]`` -> ``[N, 3]``."""
    degree = int(round(math.sqrt(sh.shape[-2]))) - 1
    b = sh_basis(dirs, degree).to(sh.dtype)  # [N, K]
    return (b[..., :, None] * sh).sum(-2)


@cache
def _probe(degree: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Fixed probe directions D [M, 3] (Fibonacci sphere, float64) and pinv(B_l(D)) per band."""
    m = 48
    i = torch.arange(m, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / m
    r = torch.sqrt(1 - z * z)
    phi = i * math.pi * (3 - math.sqrt(5))
    d = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)
    b = sh_basis(d, degree)
    pinvs = [torch.linalg.pinv(b[:, l * l : (l + 1) ** 2]) for l in range(1, degree + 1)]
    return d, pinvs


def sh_band_rotations(rot: torch.Tensor, degree: int) -> list[torch.Tensor]:
    """Per-band matrices ``A_l [..., 2l+1, 2l+1]`` (l = 1..degree) for rotations ``rot [..., 3, 3]``."""
    d, pinvs = _probe(degree)
    d = d.to(rot.dtype)
    # rows of R^T d for every probe: (R^T d)^T = d^T R
    rd = d @ rot  # [..., M, 3]
    b = sh_basis(rd, degree)  # [..., M, K]
    return [pinvs[l - 1].to(rot.dtype) @ b[..., l * l : (l + 1) ** 2] for l in range(1, degree + 1)]


def rotate_sh(sh: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """SH coefficients ``sh [N, K, 3]`` of splats rotated by ``rot`` ([3, 3] or [N, 3, 3]).

    Degree 0 is unchanged; degrees 1-3 are rotated exactly. Differentiable in both.
    """
    k = sh.shape[-2]
    degree = int(round(math.sqrt(k))) - 1
    if degree == 0:
        return sh
    mats = sh_band_rotations(rot.to(torch.float64), degree)
    parts = [sh[..., :1, :]]
    for l, a in enumerate(mats, start=1):
        band = sh[..., l * l : (l + 1) ** 2, :]
        parts.append(a.to(sh.dtype) @ band)
    return torch.cat(parts, dim=-2)
