"""References a run is matched against: a video (frames [T,H,W,3]) or a trajectory
(x [T,P,3]) read from ``.mp4`` / ``.gif`` / ``.npz``, with the file's sha256 (part of
a fit's resume fingerprint). Reading only; what to do with one is the losses' and
the fit's business. A missing or malformed file is a one-line user error.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["VIDEO_SUFFIXES", "Reference", "load_reference"]

VIDEO_SUFFIXES = (".mp4", ".gif")


@dataclass
class Reference:
    """A loaded reference: a video or a trajectory."""

    kind: Literal["video", "trajectory"]
    data: np.ndarray
    """frames [T,H,W,3] (uint8 or float in [0,1]) or x [T,P,3] float32 [m]."""
    path: str
    digest: str
    """sha256 of the file (part of the resume fingerprint)."""
    mask: np.ndarray | None = None
    """Optional video mask [T,H,W] or [H,W] in [0,1]."""


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_reference(path: str | Path) -> Reference:
    """Read ``--reference``; a missing or malformed file is a one-line user error."""
    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"{p}: reference not found (expected .mp4, .gif or .npz)")
    suffix = p.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        from motionphysics.io.video import read_video

        return Reference("video", np.asarray(read_video(p)), str(p), _digest(p))
    if suffix != ".npz":
        raise UserInputError(
            f"{p}: unsupported reference type {suffix!r}; expected .mp4, .gif or .npz"
        )
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise UserInputError(f"{p}: not a readable .npz ({err})") from None
    if "frames" in arrays:
        frames = arrays["frames"]
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise UserInputError(
                f"{p}: 'frames' must be [frames, height, width, 3], got {frames.shape}"
            )
        if frames.dtype != np.uint8:
            frames = frames.astype(np.float32)
            if frames.size and (frames.min() < 0 or frames.max() > 1):
                raise UserInputError(f"{p}: float 'frames' must lie in [0, 1]")
        return Reference("video", frames, str(p), _digest(p), mask=arrays.get("mask"))
    if "x" in arrays:
        x = arrays["x"]
        if x.ndim != 3 or x.shape[-1] != 3:
            raise UserInputError(f"{p}: 'x' must be [frames, particles, 3], got {x.shape}")
        return Reference("trajectory", x.astype(np.float32), str(p), _digest(p))
    raise UserInputError(
        f"{p}: no 'frames' (a video [T,H,W,3]) or 'x' (a trajectory [T,P,3]) array in the .npz"
    )
