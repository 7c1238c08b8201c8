"""The Gaussian-splat scene: raw (pre-activation) parameters of N 3D Gaussians.

``GaussianScene`` stores exactly what an INRIA 3DGS ``.ply`` stores, in the same
spaces (log scales, logit opacities, unnormalised wxyz quaternions, SH coefficients),
so reading and writing a file is lossless. Activated quantities (scales, unit
rotations, opacities, covariances, base colours) are derived on demand.

This module knows nothing about files, meshes or simulation; it must not import
trimesh, plyfile or warp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

from motionphysics.errors import UserInputError

__all__ = [
    "SH_C0",
    "GaussianScene",
    "num_sh_coeffs",
    "quat_to_rotmat",
    "rotmat_to_quat",
    "quat_multiply",
]

SH_C0 = 0.28209479177387814
"""Degree-0 real spherical-harmonic constant 1 / (2 sqrt(pi)); colour = 0.5 + SH_C0 * f_dc."""

_VALID_DEGREES = (0, 1, 2, 3)


def num_sh_coeffs(degree: int) -> int:
    """Number K of SH coefficients per colour channel for ``degree`` (``(d+1)^2``)."""
    return (degree + 1) ** 2


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``[..., 3, 3]`` from quaternions ``[..., 4]`` (wxyz, normalised here)."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    r = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return r.reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(r: torch.Tensor) -> torch.Tensor:
    """Unit quaternions ``[..., 4]`` (wxyz, w >= 0) from rotation matrices ``[..., 3, 3]``.

    Shepperd's method: pick the largest of (trace, diagonal) to divide by, so the
    result is accurate for every rotation (no cancellation near 180 degrees).
    """
    m = r
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    cand = torch.stack([tr, m00, m11, m22], dim=-1)
    choice = cand.argmax(dim=-1)
    out = torch.empty(*m.shape[:-2], 4, dtype=m.dtype, device=m.device)

    def _fill(mask, w, x, y, z):
        out[mask] = torch.stack([w[mask], x[mask], y[mask], z[mask]], dim=-1)

    s0 = torch.sqrt((1 + tr).clamp_min(1e-12)) * 2
    _fill(
        choice == 0,
        0.25 * s0,
        (m[..., 2, 1] - m[..., 1, 2]) / s0,
        (m[..., 0, 2] - m[..., 2, 0]) / s0,
        (m[..., 1, 0] - m[..., 0, 1]) / s0,
    )
    s1 = torch.sqrt((1 + m00 - m11 - m22).clamp_min(1e-12)) * 2
    _fill(
        choice == 1,
        (m[..., 2, 1] - m[..., 1, 2]) / s1,
        0.25 * s1,
        (m[..., 0, 1] + m[..., 1, 0]) / s1,
        (m[..., 0, 2] + m[..., 2, 0]) / s1,
    )
    s2 = torch.sqrt((1 + m11 - m00 - m22).clamp_min(1e-12)) * 2
    _fill(
        choice == 2,
        (m[..., 0, 2] - m[..., 2, 0]) / s2,
        (m[..., 0, 1] + m[..., 1, 0]) / s2,
        0.25 * s2,
        (m[..., 1, 2] + m[..., 2, 1]) / s2,
    )
    s3 = torch.sqrt((1 + m22 - m00 - m11).clamp_min(1e-12)) * 2
    _fill(
        choice == 3,
        (m[..., 1, 0] - m[..., 0, 1]) / s3,
        (m[..., 0, 2] + m[..., 2, 0]) / s3,
        (m[..., 1, 2] + m[..., 2, 1]) / s3,
        0.25 * s3,
    )
    out = out * torch.where(out[..., :1] < 0, -1.0, 1.0).to(out.dtype)
    return out / out.norm(dim=-1, keepdim=True)


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a ⊗ b`` of wxyz quaternions ``[..., 4]`` (rotation b, then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


@dataclass
class GaussianScene:
    """N 3D Gaussians in the world frame (z up, metres), stored pre-activation.

    All tensors share one device and dtype (float32 unless a caller chose otherwise).
    """

    means: torch.Tensor
    """Centres [m], shape (N, 3)."""
    log_scales: torch.Tensor
    """Natural log of the per-axis standard deviations [log m], shape (N, 3)."""
    quats: torch.Tensor
    """Orientations as wxyz quaternions, unnormalised (INRIA storage), shape (N, 4)."""
    logit_opacities: torch.Tensor
    """Opacity before the sigmoid [-], shape (N,)."""
    sh: torch.Tensor
    """Spherical-harmonic colour coefficients, shape (N, K, 3) with K = (d+1)^2,
    d in 0..3; ``sh[:, 0]`` is f_dc; ``sh[:, k, c]`` for k >= 1 is ``f_rest_{c*(K-1)+k-1}``."""

    # ---- derived ---------------------------------------------------------------------
    @property
    def num(self) -> int:
        """Number of Gaussians N."""
        return int(self.means.shape[0])

    def __len__(self) -> int:
        return self.num

    @property
    def sh_degree(self) -> int:
        """SH degree d, from K = (d+1)^2."""
        return int(round(math.sqrt(self.sh.shape[1]))) - 1

    @property
    def scales(self) -> torch.Tensor:
        """Per-axis standard deviations [m], shape (N, 3)."""
        return torch.exp(self.log_scales)

    @property
    def rotations(self) -> torch.Tensor:
        """Unit quaternions (wxyz), shape (N, 4)."""
        return self.quats / self.quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    @property
    def opacities(self) -> torch.Tensor:
        """Opacities in (0, 1) [-], shape (N,)."""
        return torch.sigmoid(self.logit_opacities)

    def rotation_matrices(self) -> torch.Tensor:
        """Rotation matrices whose columns are the Gaussians' axes, shape (N, 3, 3)."""
        return quat_to_rotmat(self.quats)

    def covariances(self) -> torch.Tensor:
        """World covariances R diag(s^2) R^T [m^2], shape (N, 3, 3)."""
        r = self.rotation_matrices()
        s2 = self.scales**2
        return (r * s2[:, None, :]) @ r.transpose(-1, -2)

    def base_colors(self) -> torch.Tensor:
        """Degree-0 RGB ``0.5 + SH_C0 * f_dc`` clamped to [0, 1], shape (N, 3)."""
        return (0.5 + SH_C0 * self.sh[:, 0, :]).clamp(0.0, 1.0)

    # ---- manipulation ----------------------------------------------------------------
    def subset(self, idx) -> GaussianScene:
        """The Gaussians selected by ``idx`` (bool mask (N,) or index tensor/array/slice)."""
        if not isinstance(idx, slice | torch.Tensor):
            idx = torch.as_tensor(idx)
        if isinstance(idx, torch.Tensor):
            idx = idx.to(self.means.device)
        return GaussianScene(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})

    def clone(self) -> GaussianScene:
        return GaussianScene(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def to(self, *args, **kwargs) -> GaussianScene:
        """``torch.Tensor.to`` applied to every field."""
        return GaussianScene(
            **{f.name: getattr(self, f.name).to(*args, **kwargs) for f in fields(self)}
        )

    @staticmethod
    def concat(scenes: list[GaussianScene]) -> GaussianScene:
        """Gaussians of several scenes together; SH degrees are padded to the highest."""
        if not scenes:
            raise ValueError("concat needs at least one scene")
        k = max(s.sh.shape[1] for s in scenes)
        shs = []
        for s in scenes:
            pad = k - s.sh.shape[1]
            shs.append(torch.nn.functional.pad(s.sh, (0, 0, 0, pad)) if pad else s.sh)
        return GaussianScene(
            means=torch.cat([s.means for s in scenes]),
            log_scales=torch.cat([s.log_scales for s in scenes]),
            quats=torch.cat([s.quats for s in scenes]),
            logit_opacities=torch.cat([s.logit_opacities for s in scenes]),
            sh=torch.cat(shs),
        )

    @staticmethod
    def from_activated(
        means, scales, rotations, opacities, colors=None, sh=None, dtype=torch.float32
    ) -> GaussianScene:
        """Build from activated values.

        means (N,3) [m]; scales (N,3) std-devs [m] (> 0); rotations (N,4) wxyz;
        opacities (N,) in (0,1); either colors (N,3) RGB in [0,1] (degree 0) or sh (N,K,3).
        """
        means = torch.as_tensor(means, dtype=dtype)
        scales = torch.as_tensor(scales, dtype=dtype)
        op = torch.as_tensor(opacities, dtype=dtype).clamp(1e-6, 1 - 1e-6)
        if sh is None:
            if colors is None:
                raise ValueError("give colors or sh")
            colors = torch.as_tensor(colors, dtype=dtype)
            sh = ((colors - 0.5) / SH_C0)[:, None, :]
        return GaussianScene(
            means=means,
            log_scales=torch.log(scales),
            quats=torch.as_tensor(rotations, dtype=dtype),
            logit_opacities=torch.log(op) - torch.log1p(-op),
            sh=torch.as_tensor(sh, dtype=dtype),
        )

    # ---- validation ------------------------------------------------------------------
    def validate(self, origin: str = "<scene>") -> GaussianScene:
        """Check shapes and finiteness; raise UserInputError naming ``origin`` and the field.

        Returns self so calls can be chained.
        """
        n = self.means.shape[0] if self.means.ndim >= 1 else -1
        expect = {
            "means": (n, 3),
            "log_scales": (n, 3),
            "quats": (n, 4),
            "logit_opacities": (n,),
        }
        for name, shape in expect.items():
            t = getattr(self, name)
            if tuple(t.shape) != shape:
                raise UserInputError(
                    f"{origin}: field '{name}' has shape {tuple(t.shape)}, expected {shape}"
                )
        sh = self.sh
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise UserInputError(
                f"{origin}: field 'sh' has shape {tuple(sh.shape)}, expected (N, K, 3)"
            )
        if sh.shape[1] not in [num_sh_coeffs(d) for d in _VALID_DEGREES]:
            raise UserInputError(
                f"{origin}: field 'sh' has {sh.shape[1]} coefficients per channel, expected 1, 4, 9 or 16"
            )
        for f in fields(self):
            t = getattr(self, f.name)
            if not torch.is_floating_point(t):
                raise UserInputError(
                    f"{origin}: field '{f.name}' must be floating point, got {t.dtype}"
                )
            bad = ~torch.isfinite(t)
            if bool(bad.any()):
                rows = bad.reshape(t.shape[0], -1).any(dim=1).nonzero()
                first = int(rows[0]) if rows.numel() else 0
                raise UserInputError(
                    f"{origin}: field '{f.name}' contains NaN or Inf "
                    f"({int(rows.numel())} Gaussians, first at index {first})"
                )
        qn = self.quats.norm(dim=-1)
        if bool((qn <= 1e-12).any()):
            first = int((qn <= 1e-12).nonzero()[0])
            raise UserInputError(f"{origin}: field 'quats' has a zero quaternion at index {first}")
        return self
