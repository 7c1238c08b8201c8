"""The one interface every optimisation loss implements.

A loss receives what the optimisation loop produced for the frames it supervises this
iteration (a :class:`Prediction`: rendered frames and/or particle states) plus a
:class:`LossContext` (iteration, random generator, frame count) and returns a scalar
torch tensor that is differentiable in the prediction. It holds its own targets
(a reference video, a reference trajectory, a video prior) from construction.

Losses declare what they need (``needs_render``, ``needs_states``) so the loop renders
only when some loss looks at pixels. This module must not import heavy packages and
must not know about the simulator or the renderer.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import Tensor

__all__ = ["Loss", "LossBuildContext", "LossContext", "Prediction"]


@dataclass(frozen=True)
class Prediction:
    """What the loop computed for the supervised frames of one iteration.

    ``frame_indices`` are indices into the run's frames (0 is the initial state, the
    last is ``sim.frames - 1``), sorted ascending; every tensor below has one entry per
    index, in that order.
    """

    frame_indices: tuple[int, ...]
    """[S] supervised frame indices."""
    xs: Tensor | None = None
    """[S, P, 3] float32 world-space particle positions [m]."""
    Fs: Tensor | None = None
    """[S, P, 3, 3] float32 deformation gradients [-]."""
    rgb: Tensor | None = None
    """[S, H, W, 3] float32 rendered frames in [0, 1]."""


@dataclass
class LossContext:
    """Per-iteration context a loss may use (stochastic losses draw from ``rng``)."""

    iteration: int
    """0-based optimisation iteration."""
    num_frames: int
    """Frames in the whole run (``sim.frames``)."""
    rng: torch.Generator = field(default_factory=torch.Generator)
    """The loop's generator; its state is checkpointed, so draws are resumable."""
    extras: dict = field(default_factory=dict)
    """Free-form per-iteration values for plug-ins (e.g. the prompt, the prior)."""


@dataclass
class LossBuildContext:
    """What a loss built from the config (``optimize.losses``) may use at construction."""

    prompt: str
    """The run's prompt (priors condition on it)."""
    prior: Any = None
    """The run's :class:`~motionphysics.priors.VideoPrior`, or None (``--prior none``)."""
    num_frames: int = 0
    """Frames in the whole run (``sim.frames``)."""
    frame_dt: float = 0.0
    """Seconds between output frames."""
    out_dir: Path | None = None
    """The run directory (a loss that samples a reference writes ``prior_reference.mp4`` here)."""
    device: str = "cpu"
    seed: int = 0
    """The optimisation seed (a loss that samples draws from a generator seeded with it)."""
    height: int = 0
    """Pixel height of the run camera (0: unknown); frames a loss compares are this tall."""
    width: int = 0
    """Pixel width of the run camera (0: unknown)."""
    num_particles: int = 0
    """Simulated particles of the prepared scene (0: unknown)."""


class Loss(ABC):
    """A scalar objective over a :class:`Prediction`.

    Subclasses set ``name`` and what they need, implement :meth:`__call__`, and may
    implement :meth:`check` to validate their targets against the run once
    (raising :class:`~motionphysics.errors.UserInputError`).
    """

    name: ClassVar[str] = "loss"
    needs_render: ClassVar[bool] = False
    """True when the loss reads ``Prediction.rgb``."""
    needs_states: ClassVar[bool] = False
    """True when the loss reads ``Prediction.xs`` / ``Prediction.Fs``."""

    Options: ClassVar[Any] = None
    """Optional strict pydantic model of the loss's config options (``optimize.losses[i]``)."""
    needs_prior: ClassVar[bool] = False
    """True when the loss cannot work without a video prior."""

    @classmethod
    def build(cls, options: Any, ctx: LossBuildContext) -> Loss:
        """Construct from validated ``options`` (an instance of ``Options``) and ``ctx``.

        Losses that need targets only the caller has (a reference video) do not
        override this and are constructed directly."""
        from motionphysics.errors import UserInputError

        raise UserInputError(f"loss {cls.name!r} cannot be built from the config alone")

    def state_dict(self) -> dict:
        """Learnable or stochastic state to checkpoint (e.g. the LMD extractor); default none."""
        return {}

    def load_state_dict(self, state: dict) -> None:  # noqa: B027 - optional hook, default no state
        """Restore what :meth:`state_dict` returned."""

    @abstractmethod
    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        """Return a 0-dim tensor, differentiable in the tensors of ``pred``."""

    def components(self) -> dict[str, float]:
        """Named parts of the last evaluated value (for ``log.jsonl``); default none."""
        return {}
