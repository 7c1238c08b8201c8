"""Dense optical flow between consecutive video frames, for ECMS.

Backends:

- ``dis`` (default): OpenCV's DIS optical flow (``cv2.DISOpticalFlow_create``, preset
  MEDIUM) on grey frames; in the main ``video`` module of ``opencv-python-headless``
  (pinned 5.0.0.93 in the ``eval`` extra), no weights.
- ``farneback``: ``cv2.calcOpticalFlowFarneback`` (pyramid 0.5, 3 levels, window 15,
  3 iterations, poly_n 5, poly_sigma 1.2), no weights.
- ``raft``: torchvision's RAFT-large from a LOCAL weights file (``--raft PATH``; e.g.
  ``raft_large_C_T_SKHT_V1-0b8c9e55.pth``, the port of the original ``raft-sintel.pth``),
  12 flow updates, the last one taken. Needs torchvision, which this project does not
  install; asking for it without torchvision is a one-line user error, never a silent
  switch to another backend.

All backends return the forward flow ``F_{l,l+1}`` [L, H, W, 2] float32 in PIXELS of
the frames they were given (``[..., 0]`` along x / columns, ``[..., 1]`` along y /
rows): ``frame_{l+1}(p + F(p)) ~ frame_l(p)``. Resizing to a fixed flow resolution is
the caller's choice (``metrics.ecms``). This module must not decide what a score is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["FLOW_METHODS", "compute_flows", "resize_frames"]

FLOW_METHODS = ("dis", "farneback", "raft")


def _cv2():
    try:
        import cv2
    except ImportError:  # pragma: no cover - the eval extra installs it
        raise UserInputError(
            "--flow dis|farneback: needs opencv-python-headless (pip install 'motionphysics[eval]')"
        ) from None
    return cv2


def resize_frames(frames: np.ndarray, height: int | None) -> np.ndarray:
    """Frames [T, H, W, 3] uint8 resized (area filter) to ``height`` rows, width by aspect.

    The width is rounded to the nearest multiple of 8 (RAFT needs it; the other
    backends do not care), so the aspect ratio may change by < 4 px / W. ``None``:
    unchanged.
    """
    frames = np.asarray(frames)
    if height is None or frames.shape[1] == height:
        return frames
    cv2 = _cv2()
    T, H, W = frames.shape[:3]
    w = max(8, int(round(W * height / H / 8.0)) * 8)
    interp = cv2.INTER_AREA if height < H else cv2.INTER_CUBIC
    return np.stack([cv2.resize(f, (w, int(height)), interpolation=interp) for f in frames])


def _grey(frame: np.ndarray, cv2) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(frame, dtype=np.uint8), cv2.COLOR_RGB2GRAY)


def _dis(frames: np.ndarray) -> np.ndarray:
    cv2 = _cv2()
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    grey = [_grey(f, cv2) for f in frames]
    return np.stack([dis.calc(grey[i], grey[i + 1], None) for i in range(len(grey) - 1)])


def _farneback(frames: np.ndarray) -> np.ndarray:
    cv2 = _cv2()
    grey = [_grey(f, cv2) for f in frames]
    return np.stack(
        [
            cv2.calcOpticalFlowFarneback(grey[i], grey[i + 1], None, 0.5, 3, 15, 3, 5, 1.2, 0)
            for i in range(len(grey) - 1)
        ]
    )


def _raft(frames: np.ndarray, weights: str | Path | None, device: str) -> np.ndarray:
    try:
        from torchvision.models.optical_flow import raft_large
    except ImportError:
        raise UserInputError(
            "--flow raft: needs torchvision, which is not installed (use --flow dis or farneback)"
        ) from None
    if weights is None:
        raise UserInputError(
            "--flow raft: pass --raft PATH (a local torchvision RAFT-large state dict .pth)"
        )
    weights = Path(weights)
    if not weights.is_file():
        raise UserInputError(f"--raft {weights}: file not found")
    import torch

    model = raft_large(weights=None, progress=False)
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
        model.load_state_dict(state, strict=True)
    except (RuntimeError, OSError, ValueError) as err:
        raise UserInputError(
            f"--raft {weights}: not a RAFT-large state dict ({str(err).splitlines()[0]})"
        ) from None
    model = model.eval().to(device)
    T, H, W = frames.shape[:3]
    if H % 8 or W % 8 or min(H, W) < 128:
        raise UserInputError(
            f"--flow raft: frames must be at least 128 px with sides divisible by 8, got {H}x{W} "
            "(set the flow height, e.g. 256)"
        )
    x = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 255.0
    x = (x * 2.0 - 1.0).to(device)  # RAFT's preset: [0, 1] -> [-1, 1]
    out = []
    with torch.no_grad():
        for i in range(T - 1):
            flow = model(x[i : i + 1], x[i + 1 : i + 2], num_flow_updates=12)[-1]
            out.append(flow[0].permute(1, 2, 0).cpu().numpy())
    return np.stack(out).astype(np.float32)


def compute_flows(
    frames: np.ndarray,
    method: str = "dis",
    *,
    raft_weights: str | Path | None = None,
    device: str = "cpu",
) -> np.ndarray:
    """Forward flows between consecutive frames.

    Parameters
    ----------
    frames: uint8 [T, H, W, 3] RGB, T >= 2.
    method: ``dis`` | ``farneback`` | ``raft``.
    raft_weights: local RAFT-large state dict (``raft`` only).

    Returns
    -------
    float32 [T-1, H, W, 2]: F_{l,l+1} in pixels (x, y).
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames must be uint8 [T, H, W, 3], got {frames.dtype} {frames.shape}")
    if frames.shape[0] < 2:
        raise UserInputError(f"optical flow needs at least 2 frames, got {frames.shape[0]}")
    if method == "dis":
        flows = _dis(frames)
    elif method == "farneback":
        flows = _farneback(frames)
    elif method == "raft":
        flows = _raft(frames, raft_weights, device)
    else:
        raise UserInputError(f"--flow: expected one of {', '.join(FLOW_METHODS)}, got {method!r}")
    return np.asarray(flows, dtype=np.float32)
