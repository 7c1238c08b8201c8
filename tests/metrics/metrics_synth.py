"""Synthetic videos with a known optical flow (shared by the metric tests)."""

from __future__ import annotations

import numpy as np


def texture(xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    """A smooth, non-periodic-looking grey texture in [~40, ~215] (float64)."""
    v = 128.0
    for kx, ky, ph, a in (
        (1 / 9.0, 1 / 13.0, 0.3, 30),
        (1 / 17.0, -1 / 7.0, 1.1, 25),
        (1 / 5.5, 1 / 21.0, 2.0, 20),
        (-1 / 11.0, 1 / 6.0, 0.7, 12),
    ):
        v = v + a * np.sin(2 * np.pi * (kx * xx + ky * yy) + ph)
    return v


def translating_video(shifts: np.ndarray, h: int = 64, w: int = 80) -> np.ndarray:
    """Frames [T, h, w, 3] uint8 with frame l = texture(x - sx_l, y - sy_l).

    ``shifts`` [T, 2] px (x, y); the true flow from l to l+1 is shifts[l+1] - shifts[l]
    at every pixel.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    frames = []
    for sx, sy in np.asarray(shifts, dtype=np.float64):
        g = texture(xx - sx, yy - sy)
        frames.append(np.repeat(np.clip(np.round(g), 0, 255).astype(np.uint8)[..., None], 3, -1))
    return np.stack(frames)
