"""trajectory_match: L2 and Chamfer values, chunking, permutation invariance, errors."""

import numpy as np
import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.losses import LossContext, Prediction
from motionphysics.losses import trajectory_match as tm
from motionphysics.losses.trajectory_match import TrajectoryMatchLoss, chamfer_distance


def _chamfer_numpy(a, b):
    d = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return 0.5 * (d.min(1).mean() + d.min(0).mean())


def test_l2_value():
    ref = torch.zeros(3, 4, 3)
    loss = TrajectoryMatchLoss(ref)
    pred = torch.zeros(1, 4, 3)
    pred[0, :, 0] = 0.5  # every particle 0.5 m off: squared distance 0.25
    assert float(loss(Prediction((2,), xs=pred), LossContext(0, 3))) == pytest.approx(0.25)


def test_chamfer_matches_numpy_and_ignores_order(monkeypatch):
    rng = np.random.default_rng(1)
    a, b = rng.random((50, 3)), rng.random((40, 3))
    want = _chamfer_numpy(a, b)
    got = float(chamfer_distance(torch.tensor(a), torch.tensor(b)))
    assert got == pytest.approx(want, rel=1e-12)
    monkeypatch.setattr(tm, "_CHUNK_ENTRIES", 100)  # forces blocks of 2-3 rows
    assert float(chamfer_distance(torch.tensor(a), torch.tensor(b))) == pytest.approx(
        want, rel=1e-12
    )
    ref = torch.tensor(a, dtype=torch.float32)[None].expand(2, 50, 3)
    loss = TrajectoryMatchLoss(ref, metric="chamfer")
    perm = torch.randperm(50)
    assert float(loss(Prediction((1,), xs=ref[:1, perm]), LossContext(0, 2))) == pytest.approx(
        0.0, abs=1e-12
    )


def test_reference_checks():
    loss = TrajectoryMatchLoss(np.zeros((5, 7, 3)), source="traj.npz")
    loss.check(5, 7)
    with pytest.raises(
        UserInputError, match="traj.npz: reference has 5 frames but config sim.frames is 9"
    ):
        loss.check(9, 7)
    with pytest.raises(UserInputError, match="reference has 7 particles .* prepares 8"):
        loss.check(5, 8)
    with pytest.raises(UserInputError, match=r"\[frames, particles, 3\]"):
        TrajectoryMatchLoss(np.zeros((5, 7)))
    with pytest.raises(UserInputError, match="trajectory_metric"):
        TrajectoryMatchLoss(np.zeros((5, 7, 3)), metric="hausdorff")
