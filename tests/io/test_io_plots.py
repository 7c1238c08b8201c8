"""Plots: loss / parameter curves and space-time slices produce real PNGs."""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.io.plots import plot_loss, plot_params, slice_image, space_time_slice


def _png(path):
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


def test_plot_loss_and_params(tmp_path):
    recs = [
        {
            "iteration": i,
            "loss": 1.0 / (i + 1),
            "loss_lmd": 0.5 / (i + 1),
            "params": {"E": 1e6 * (1 + i), "nu": 0.3},
        }
        for i in range(5)
    ]
    w, h = _png(plot_loss(recs, tmp_path / "loss.png"))
    assert w > 100 and h > 100
    _png(plot_params(recs, {"E": (1e5, 1e8), "nu": (0.1, 0.5)}, tmp_path / "params.png"))


def test_plot_loss_rejects_empty(tmp_path):
    with pytest.raises(ValueError):
        plot_loss([{"iteration": 0}], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_slice_picks_the_right_pixels():
    T, H, W = 5, 6, 7
    frames = np.zeros((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t, 2, t, 0] = 255  # a dot moving right along row 2
    sl = slice_image(frames, "row", 2)
    assert sl.shape == (T, W, 3)
    assert [int(np.argmax(sl[t, :, 0])) for t in range(T)] == list(range(T))
    col = slice_image(frames.astype(np.float32) / 255, "col", 3)
    assert col.shape == (T, H, 3) and col[3, 2, 0] == 255 and col[2, 2, 0] == 0
    with pytest.raises(ValueError):
        slice_image(frames, "row", H)


def test_space_time_slice_png(tmp_path):
    frames = np.random.default_rng(0).random((8, 16, 20, 3)).astype(np.float32)
    sl = space_time_slice(frames, tmp_path / "s.png", axis="col", frame_dt=0.04)
    assert sl.shape == (8, 16, 3) and sl.dtype == np.uint8
    _png(tmp_path / "s.png")
