"""Splats that follow the simulation: the hook between simulator output and renderer.

A splat attached to particle ``p`` (``parent``) with rest offset ``o`` and rest
covariance ``Σ`` is drawn at time t with centre ``x_t[p] + F_t[p] o``, covariance
``F Σ Fᵀ`` and view-dependent colour evaluated at ``Rᵀ d`` where ``R`` is the
rotation of the polar decomposition ``F = R S`` and ``d`` the view direction
(camera centre -> splat centre) (PhysGaussian). Everything is differentiable in
``x`` and ``F`` (and in the splats' own tensors); the polar rotation has an analytic
backward that stays finite at ``F = I`` where an SVD backward is not.

This module draws nothing itself except in :func:`render_frames`.
"""

from __future__ import annotations

import torch

from motionphysics.render.camera import Camera
from motionphysics.render.sh import sh_to_rgb

__all__ = ["polar_rotation", "deform_splats", "render_frames", "render_scene"]


def _skew(v: torch.Tensor) -> torch.Tensor:
    """``[..., 3]`` -> the cross-product matrices ``[..., 3, 3]``."""
    z = torch.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return torch.stack(
        [
            torch.stack([z, -w, y], -1),
            torch.stack([w, z, -x], -1),
            torch.stack([-y, x, z], -1),
        ],
        -2,
    )


def _inv_transpose(X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(cofactor matrix ``[..., 3, 3]`` = det * X^{-T}, det ``[...]``) by cross products of rows."""
    r0, r1, r2 = X[..., 0, :], X[..., 1, :], X[..., 2, :]
    cof = torch.stack(
        [torch.linalg.cross(r1, r2), torch.linalg.cross(r2, r0), torch.linalg.cross(r0, r1)], -2
    )
    return cof, (r0 * cof[..., 0, :]).sum(-1)


def _polar_newton(F: torch.Tensor, max_iter: int = 40) -> torch.Tensor:
    """Rotation of ``F [B, 3, 3]`` by Newton's iteration ``X <- (g X + X^{-T} / g) / 2``.

    ``g = |det X|^{-1/3}`` (determinant scaling) gives quadratic convergence from the
    first step; ~5 iterations for strains of tens of percent. An order of magnitude
    faster than batched SVD on CPU (measured 0.25 s for 20k matrices). Matrices with
    ``det F <= 0`` (inverted elements, rare) go through the SVD with the det fix.
    """
    tol = 1e-6 if F.dtype == torch.float32 else 1e-13
    good = torch.det(F) > 0
    eye = torch.eye(3, dtype=F.dtype, device=F.device)
    X = torch.where(good[..., None, None], F, eye)  # bad ones are redone below
    for _ in range(max_iter):
        cof, det = _inv_transpose(X)
        g = det.abs().pow(-1.0 / 3.0)[..., None, None]
        X_new = 0.5 * (g * X + cof / (g * det[..., None, None]))
        delta = (X_new - X).abs().amax() if X.numel() else torch.zeros(())
        X = X_new
        if float(delta) < tol:
            break
    if not bool(good.all()):
        U, _, Vh = torch.linalg.svd(F[~good])
        D = torch.ones_like(U[..., 0])
        D[..., 2] = torch.sign(torch.det(U @ Vh))
        X = X.clone()
        X[~good] = (U * D[..., None, :]) @ Vh
    return X


class _PolarRotation(torch.autograd.Function):
    """R of ``F = R S`` (R proper rotation, S symmetric) with the analytic VJP.

    With ``Ω = Rᵀ dR = [ω]×``: ``Ω S + S Ω = Rᵀ dF - dFᵀ R`` gives
    ``ω = (tr(S) I - S)^{-1} vee(Rᵀ dF - dFᵀ R)``; hence for a cotangent ``G``,
    ``dL/dF = R [b]×`` with ``b = (tr(S) I - S)^{-1} a`` and ``a`` the axial vector
    of ``Rᵀ G`` (``a = (A32 - A23, A13 - A31, A21 - A12)``).
    """

    @staticmethod
    def forward(ctx, F):  # noqa: D102
        R = _polar_newton(F)
        ctx.save_for_backward(F, R)
        return R

    @staticmethod
    def backward(ctx, G):  # noqa: D102
        F, R = ctx.saved_tensors
        S = R.transpose(-1, -2) @ F
        S = 0.5 * (S + S.transpose(-1, -2))
        eye = torch.eye(3, dtype=F.dtype, device=F.device)
        K = S.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None] * eye - S
        # K is positive definite for det F > 0; tiny ridge keeps inverted/flat F finite.
        K = K + 1e-12 * eye
        A = R.transpose(-1, -2) @ G
        a = torch.stack(
            [A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]],
            -1,
        )
        b = torch.linalg.solve(K, a.unsqueeze(-1)).squeeze(-1)
        return R @ _skew(b)


def polar_rotation(F: torch.Tensor) -> torch.Tensor:
    """Rotation ``R [..., 3, 3]`` of the polar decomposition of ``F [..., 3, 3]`` (det R = +1)."""
    shape = F.shape
    return _PolarRotation.apply(F.reshape(-1, 3, 3)).reshape(shape)


def deform_splats(
    splats,
    x: torch.Tensor,
    F: torch.Tensor,
    parent: torch.Tensor,
    offset: torch.Tensor,
    camera: Camera,
):
    """Deformed splats for one frame.

    Args:
        splats: rest-state :class:`~motionphysics.scene.gaussians.GaussianScene`, N splats.
        x: ``[P, 3]`` particle positions [m] at this frame.
        F: ``[P, 3, 3]`` particle deformation gradients [-].
        parent: ``[N] long`` particle each splat follows.
        offset: ``[N, 3]`` rest offset splat mean - parent position [m].
        camera: the view (for view-dependent colour).

    Returns:
        ``(means [N, 3] m, covs [N, 3, 3] m², colors [N, 3])``, differentiable in
        ``x``, ``F`` and the splats' tensors.
    """
    Fp = F[parent]  # [N, 3, 3]
    means = x[parent] + (Fp @ offset.unsqueeze(-1)).squeeze(-1)
    sigma = splats.covariances().to(Fp)
    covs = Fp @ sigma @ Fp.transpose(-1, -2)
    sh = splats.sh.to(Fp)
    if sh.shape[1] == 1:
        colors = sh_to_rgb(sh, means)  # degree 0 does not depend on the direction
    else:
        R = polar_rotation(Fp)
        d = means - camera.position.to(means)
        d_rest = (R.transpose(-1, -2) @ d.unsqueeze(-1)).squeeze(-1)
        colors = sh_to_rgb(sh, d_rest)
    return means, covs, colors


def render_frames(
    sim_scene,
    xs: torch.Tensor,
    Fs: torch.Tensor,
    camera: Camera,
    background=(1.0, 1.0, 1.0),
    backend: str = "auto",
) -> torch.Tensor:
    """Render a simulated sequence: ``xs [T, P, 3]``, ``Fs [T, P, 3, 3]`` -> rgb ``[T, H, W, 3]``.

    ``sim_scene`` provides ``splats``, ``splat_parent [N]`` and ``splat_offset [N, 3]``
    (CONTRACTS.md, SimScene). Differentiable in ``xs`` and ``Fs``.
    """
    from motionphysics.render.rasterize import rasterize

    splats = sim_scene.splats
    parent = sim_scene.splat_parent.to(xs.device).long()
    offset = sim_scene.splat_offset.to(xs)
    opacities = splats.opacities.to(xs)
    frames = []
    for t in range(xs.shape[0]):
        means, covs, colors = deform_splats(splats, xs[t], Fs[t], parent, offset, camera)
        frames.append(rasterize(means, covs, colors, opacities, camera, background, backend).rgb)
    return torch.stack(frames)


def render_scene(scene, camera: Camera, background=(1.0, 1.0, 1.0), backend: str = "auto"):
    """Render a rest-state :class:`~motionphysics.scene.gaussians.GaussianScene` as it is.

    View-dependent colour from the full SH degree; returns a
    :class:`~motionphysics.render.rasterize.RenderOutput`.
    """
    from motionphysics.render.rasterize import rasterize

    means = scene.means
    colors = sh_to_rgb(scene.sh, means - camera.position.to(means))
    return rasterize(
        means, scene.covariances(), colors, scene.opacities, camera, background, backend
    )
