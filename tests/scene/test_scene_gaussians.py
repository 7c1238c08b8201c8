"""GaussianScene derived quantities and SH rotation, against float64 brute-force references."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motionphysics.scene.gaussians import (
    SH_C0,
    GaussianScene,
    quat_multiply,
    quat_to_rotmat,
    rotmat_to_quat,
)
from motionphysics.scene.sh import eval_sh, rotate_sh


def test_covariances_match_brute_force():
    rng = np.random.default_rng(0)
    n = 50
    q = rng.normal(size=(n, 4)) * 2.5  # unnormalised, wxyz
    ls = rng.normal(size=(n, 3)) - 2
    s = GaussianScene(
        means=torch.zeros(n, 3, dtype=torch.float64),
        log_scales=torch.from_numpy(ls),
        quats=torch.from_numpy(q),
        logit_opacities=torch.zeros(n, dtype=torch.float64),
        sh=torch.zeros(n, 1, 3, dtype=torch.float64),
    )
    r = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is xyzw
    want = r @ (np.exp(2 * ls)[:, :, None] * np.eye(3)) @ r.transpose(0, 2, 1)
    np.testing.assert_allclose(s.covariances().numpy(), want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(s.rotation_matrices().numpy(), r, atol=1e-12)


def test_quaternion_helpers_round_trip_and_compose():
    r = Rotation.random(200, random_state=1)
    m = torch.from_numpy(r.as_matrix())
    q = rotmat_to_quat(m)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(quat_to_rotmat(q).numpy(), r.as_matrix(), atol=1e-12)
    # Near-180-degree rotations are the hard case for naive conversions.
    flips = torch.from_numpy(Rotation.from_rotvec(np.pi * np.eye(3) * (1 - 1e-9)).as_matrix())
    np.testing.assert_allclose(
        quat_to_rotmat(rotmat_to_quat(flips)).numpy(), flips.numpy(), atol=1e-8
    )
    a, b = q[:100], q[100:]
    np.testing.assert_allclose(
        quat_to_rotmat(quat_multiply(a, b)).numpy(),
        (quat_to_rotmat(a) @ quat_to_rotmat(b)).numpy(),
        atol=1e-12,
    )


def test_base_colors_subset_concat():
    s = GaussianScene.from_activated(
        means=np.zeros((3, 3)),
        scales=np.full((3, 3), 0.1),
        rotations=np.tile([1.0, 0, 0, 0], (3, 1)),
        opacities=[0.1, 0.5, 0.9],
        colors=[[0, 0.5, 1], [1, 1, 1], [0.2, 0.3, 0.4]],
    )
    np.testing.assert_allclose(
        s.base_colors().numpy(), [[0, 0.5, 1], [1, 1, 1], [0.2, 0.3, 0.4]], atol=1e-6
    )
    np.testing.assert_allclose(s.opacities.numpy(), [0.1, 0.5, 0.9], atol=1e-6)
    np.testing.assert_allclose(
        s.sh[:, 0].numpy(),
        (np.array([[0, 0.5, 1], [1, 1, 1], [0.2, 0.3, 0.4]]) - 0.5) / SH_C0,
        rtol=1e-6,
    )
    sub = s.subset(torch.tensor([False, True, True]))
    assert sub.num == 2 and torch.equal(sub.sh, s.sh[1:])
    hi = GaussianScene(s.means, s.log_scales, s.quats, s.logit_opacities, torch.ones(3, 16, 3))
    both = GaussianScene.concat([s, hi])
    assert both.num == 6 and both.sh_degree == 3
    assert torch.equal(both.sh[:3, 1:], torch.zeros(3, 15, 3))


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotate_sh_keeps_appearance_attached(degree):
    """f'(R d) = f(d) for random directions: exact up to float64 round-off."""
    g = torch.Generator().manual_seed(degree)
    k = (degree + 1) ** 2
    sh = torch.randn(20, k, 3, generator=g, dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.randn(20, 3, generator=g, dtype=torch.float64), dim=-1)
    r = torch.from_numpy(Rotation.random(random_state=degree).as_matrix())
    new = rotate_sh(sh, r)
    torch.testing.assert_close(eval_sh(new, d @ r.T), eval_sh(sh, d), rtol=0, atol=1e-12)
    assert torch.equal(new[:, 0], sh[:, 0])
    # Batched, one rotation per splat.
    rb = torch.from_numpy(Rotation.random(20, random_state=9).as_matrix())
    newb = rotate_sh(sh, rb)
    torch.testing.assert_close(
        eval_sh(newb, torch.einsum("nij,nj->ni", rb, d)), eval_sh(sh, d), rtol=0, atol=1e-12
    )
    torch.testing.assert_close(
        rotate_sh(sh, torch.eye(3, dtype=torch.float64)), sh, rtol=0, atol=1e-12
    )


def test_rotate_sh_matches_3dgs_band1_closed_form():
    """Band 1 of 3DGS is (-y, z, -x) * C1: its rotation is a signed permutation of R."""
    r = torch.from_numpy(Rotation.random(random_state=5).as_matrix())
    sh = torch.zeros(1, 4, 3, dtype=torch.float64)
    sh[0, 3, 0] = 1.0  # coefficient of -C1 * x in the red channel: f(d) = -C1 d_x
    new = rotate_sh(sh, r)
    # f'(d) = f(R^T d) = -C1 (R^T d)_x = -C1 (R[0,0] x + R[1,0] y + R[2,0] z)
    # = R[1,0] * (-C1 y) + (-R[2,0]) * (C1 z) + R[0,0] * (-C1 x)
    want = torch.tensor([r[1, 0], -r[2, 0], r[0, 0]], dtype=torch.float64)
    torch.testing.assert_close(new[0, 1:, 0], want, rtol=0, atol=1e-12)


def test_rotate_sh_gradients_match_finite_differences():
    """rotate_sh is differentiable in the coefficients and the rotation (used by callers
    that rotate SH per splat): torch.autograd.gradcheck, central differences in float64."""
    g = torch.Generator().manual_seed(0)
    sh = torch.randn(2, 16, 3, generator=g, dtype=torch.float64, requires_grad=True)
    r = torch.from_numpy(Rotation.random(2, random_state=3).as_matrix()).requires_grad_(True)
    assert torch.autograd.gradcheck(rotate_sh, (sh, r), eps=1e-6, atol=1e-7)
