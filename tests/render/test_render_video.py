"""Video and image IO round trips (imageio-ffmpeg H.264 and GIF)."""

import numpy as np
import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.io.video import read_video, to_uint8, write_image, write_video


def _frames(t=6, h=34, w=50):
    # Smooth gradients with a moving bar: survives lossy coding within a few levels.
    y, x = np.mgrid[0:h, 0:w]
    out = np.zeros((t, h, w, 3))
    for k in range(t):
        out[k, ..., 0] = x / w
        out[k, ..., 1] = y / h
        out[k, ..., 2] = ((x // 6) == k).astype(float)
    return out


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_round_trip_frame_count_and_size(tmp_path, suffix):
    frames = _frames()
    path = write_video(torch.tensor(frames, dtype=torch.float32), tmp_path / f"v{suffix}", fps=12)
    back = read_video(path)
    assert back.shape == (6, 34, 50, 3) and back.dtype == np.uint8
    # H.264 yuv420p at quality 8 and the GIF palette both stay within ~10 levels on average.
    assert np.abs(back.astype(float) - to_uint8(frames).astype(float)).mean() < 10
    assert not list(tmp_path.glob(".*partial*"))


def test_odd_sizes_are_padded_for_h264(tmp_path):
    back = read_video(write_video(_frames(3, 33, 47), tmp_path / "odd.mp4", fps=10))
    assert back.shape == (3, 34, 48, 3)


def test_uint8_frames_and_png(tmp_path):
    img = (np.random.default_rng(0).random((20, 30, 3)) * 255).astype(np.uint8)
    import imageio.v2 as imageio

    write_image(img, tmp_path / "a.png")
    assert np.array_equal(imageio.imread(tmp_path / "a.png"), img)


def test_bad_video_input(tmp_path):
    with pytest.raises(UserInputError, match=r"\.mp4 or \.gif"):
        write_video(_frames(), tmp_path / "v.avi")
    with pytest.raises(UserInputError, match=r"\[T, H, W, 3\]"):
        write_video(np.zeros((4, 4, 3)), tmp_path / "v.mp4")
    with pytest.raises(UserInputError, match="not found"):
        read_video(tmp_path / "missing.mp4")
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(UserInputError, match="cannot read"):
        read_video(tmp_path / "junk.mp4")
