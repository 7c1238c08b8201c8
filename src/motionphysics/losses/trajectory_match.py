"""``trajectory_match``: particle positions against a reference trajectory.

For system identification from a simulated (or tracked) trajectory, e.g. the
``trajectory.npz`` that ``motionphysics simulate`` writes (``x`` [frames, particles, 3],
world frame). Two metrics:

- ``l2``: mean over frames and particles of the squared distance between corresponding
  particles [m^2] (needs the same particles in the same order);
- ``chamfer``: symmetric Chamfer distance (mean squared nearest-neighbour distance, both
  ways) [m^2], for point sets without correspondence.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction

__all__ = ["TrajectoryMatchLoss", "chamfer_distance"]

# Pairwise distance blocks of at most this many entries (~64 MB in float32) keep the
# Chamfer distance usable at 20k particles without materialising a P x P matrix.
_CHUNK_ENTRIES = 16_000_000


def _min_sq_dist(a: Tensor, b: Tensor) -> Tensor:
    """For each point of a [N,3], squared distance to its nearest point of b [M,3] -> [N]."""
    rows = max(1, _CHUNK_ENTRIES // max(1, b.shape[0]))
    out = []
    for start in range(0, a.shape[0], rows):
        # The matmul form of cdist loses ~1e-8 m^2 to cancellation in float32: as large
        # as the millimetre-scale residuals a fit ends with, so use direct differences.
        d = (
            torch.cdist(a[start : start + rows], b, compute_mode="donot_use_mm_for_euclid_dist")
            ** 2
        )
        out.append(d.min(dim=1).values)
    return torch.cat(out)


def chamfer_distance(a: Tensor, b: Tensor) -> Tensor:
    """Symmetric Chamfer distance between point sets a [N,3] and b [M,3] [m^2]."""
    return 0.5 * (_min_sq_dist(a, b).mean() + _min_sq_dist(b, a).mean())


class TrajectoryMatchLoss(Loss):
    """Distance of simulated particle positions to reference positions.

    reference: [T, P, 3] float world positions [m], one entry per run frame.
    """

    name: ClassVar[str] = "trajectory_match"
    needs_states: ClassVar[bool] = True

    class Options(BaseModel):
        """``optimize.losses: [{type: trajectory_match, reference: FILE, metric: l2}]``."""

        model_config = ConfigDict(extra="forbid")
        reference: str
        """Reference trajectory: .npz with ``x`` [frames, particles, 3] (a trajectory.npz)."""
        metric: Literal["l2", "chamfer"] = "l2"
        """``l2`` (corresponding particles) or ``chamfer`` (point sets)."""

    @classmethod
    def build(cls, options: Options, ctx: LossBuildContext) -> TrajectoryMatchLoss:
        """Read the reference of ``options`` and check it against the run of ``ctx``."""
        from motionphysics.io.reference import load_reference

        ref = load_reference(options.reference)
        if ref.kind != "trajectory":
            raise UserInputError(
                f"{ref.path}: trajectory_match needs a trajectory reference (x), got a video"
            )
        loss = cls(ref.data, metric=options.metric, source=ref.path)
        if ctx.num_frames and ctx.num_particles:
            loss.check(ctx.num_frames, ctx.num_particles, "the run config's")
        return loss

    def __init__(
        self,
        reference,
        metric: Literal["l2", "chamfer"] = "l2",
        source: str = "reference",
    ):
        ref = torch.as_tensor(np.asarray(reference), dtype=torch.float32)
        if ref.ndim != 3 or ref.shape[-1] != 3:
            raise UserInputError(
                f"{source}: 'x' must have shape [frames, particles, 3], got {tuple(ref.shape)}"
            )
        if not torch.isfinite(ref).all():
            raise UserInputError(f"{source}: 'x' holds NaN or infinite positions")
        if metric not in ("l2", "chamfer"):
            raise UserInputError(
                f"optimize.trajectory_metric: expected 'l2' or 'chamfer', got {metric!r}"
            )
        self.reference = ref
        self.metric = metric
        self.source = source

    def check(self, num_frames: int, num_particles: int, config: str = "config") -> None:
        """Refuse a reference whose frame or particle count differs from the run."""
        t, p = int(self.reference.shape[0]), int(self.reference.shape[1])
        if t != num_frames:
            raise UserInputError(
                f"{self.source}: reference has {t} frames but {config} sim.frames is {num_frames}"
            )
        if p != num_particles:
            raise UserInputError(
                f"{self.source}: reference has {p} particles but the scene of {config} "
                f"prepares {num_particles}"
            )

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        if pred.xs is None:
            raise ValueError("trajectory_match needs particle positions (Prediction.xs)")
        idx = torch.as_tensor(pred.frame_indices, dtype=torch.long)
        ref = self.reference[idx].to(pred.xs.device)  # [S, P, 3]
        if self.metric == "l2":
            return ((pred.xs - ref) ** 2).sum(dim=-1).mean()
        return torch.stack(
            [chamfer_distance(p, r) for p, r in zip(pred.xs, ref, strict=True)]
        ).mean()
