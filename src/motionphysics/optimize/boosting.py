"""Frame boosting (MotionPhysics sec. 4, after DreamPhysics / PhysDreamer).

The supervised frames of a run (1 .. frames-1; frame 0 is the given initial state) are
split into M interleaved subsequences ``V_i = {i+1, i+1+M, i+1+2M, ...}`` for
``i = 0 .. M-1`` and successive iterations supervise successive subsequences. The
simulator still integrates every substep between the supervised frames; only the loss
sees fewer frames, which shortens renders and the backward pass and lets gradients
from many frame offsets alternate. When the run has fewer than M supervised frames, M
shrinks to their count so no subsequence is empty.
"""

from __future__ import annotations

__all__ = ["effective_boost", "prior_boost", "subsequences", "frames_for_iteration"]

MIN_CLIP_FRAMES = 16
"""The fewest frames a subsequence shown to a video prior should have (or the prior's own
frame count, when smaller): a clip of two or three frames stretched to the prior's length
shows it no motion it was trained on."""


def effective_boost(num_frames: int, boost: int) -> int:
    """M actually used for a run of ``num_frames`` frames (at least one supervised frame)."""
    if num_frames < 2:
        raise ValueError("frame boosting needs at least 2 frames (frame 0 is the initial state)")
    if boost < 1:
        raise ValueError(f"boost must be >= 1, got {boost}")
    return min(boost, num_frames - 1)


def subsequences(num_frames: int, boost: int) -> list[tuple[int, ...]]:
    """The M interleaved subsequences of supervised frame indices, each ascending."""
    m = effective_boost(num_frames, boost)
    return [tuple(range(1 + i, num_frames, m)) for i in range(m)]


def frames_for_iteration(iteration: int, num_frames: int, boost: int) -> tuple[int, ...]:
    """Supervised frames of 0-based ``iteration``: subsequence ``iteration mod M``."""
    subs = subsequences(num_frames, boost)
    return subs[iteration % len(subs)]


def prior_boost(num_frames: int, boost: int, prior_frames: int) -> int:
    """M for a video prior that takes ``prior_frames`` frames: the largest M <= ``boost``
    whose shortest subsequence has at least min(prior_frames, MIN_CLIP_FRAMES) frames, and
    1 when even that is too many (the paper: 150 frames, M = 8, 18 frames each; a
    16-frame run with M = 8 would give the prior clips of 1-2 frames)."""
    m = effective_boost(num_frames, boost)
    need = max(1, min(int(prior_frames), MIN_CLIP_FRAMES))
    while m > 1 and (num_frames - 1) // m < need:
        m -= 1
    return m
