"""Write and read videos (.mp4 H.264 yuv420p through imageio-ffmpeg; .gif) and images.

Frames are ``[T, H, W, 3]``: uint8, or float in [0, 1] (clipped, rounded). H.264 with
yuv420p needs even sizes: odd heights/widths are padded by repeating the last row /
column (never resampled), so a round trip returns the padded size. imageio is
imported inside the functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["write_video", "read_video", "write_image", "to_uint8"]

VIDEO_SUFFIXES = (".mp4", ".gif")


def to_uint8(frames) -> np.ndarray:
    """Frames (torch or numpy; uint8, or float in [0, 1]) -> uint8 numpy of the same shape."""
    if hasattr(frames, "detach"):
        frames = frames.detach().cpu().numpy()
    arr = np.asarray(frames)
    if arr.dtype == np.uint8:
        return arr
    if not np.issubdtype(arr.dtype, np.floating):
        raise UserInputError(f"frames: expected uint8 or float in [0, 1], got dtype {arr.dtype}")
    arr = np.nan_to_num(arr, nan=0.0)
    return (np.clip(arr, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _pad_even(frames: np.ndarray) -> np.ndarray:
    h, w = frames.shape[1:3]
    ph, pw = h % 2, w % 2
    if ph or pw:
        frames = np.pad(frames, ((0, 0), (0, ph), (0, pw), (0, 0)), mode="edge")
    return frames


def write_video(frames, path: str | Path, fps: float = 25.0) -> Path:
    """Write ``frames [T, H, W, 3]`` to ``path`` (.mp4 or .gif); returns the path.

    The file is written beside the target and renamed, so a crash never leaves a
    half-written video under the final name.
    """
    import imageio.v2 as imageio

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise UserInputError(f"{path}: video must end in .mp4 or .gif")
    arr = to_uint8(frames)
    if arr.ndim != 4 or arr.shape[-1] != 3 or arr.shape[0] < 1:
        raise UserInputError(f"{path}: frames must be [T, H, W, 3] with T >= 1, got {arr.shape}")
    if not fps > 0:
        raise UserInputError(f"{path}: fps must be positive, got {fps}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{suffix}")
    if suffix == ".mp4":
        arr = _pad_even(arr)
        writer = imageio.get_writer(
            tmp,
            format="FFMPEG",
            mode="I",
            fps=fps,
            codec="libx264",
            pixelformat="yuv420p",
            quality=8,
            macro_block_size=1,
            output_params=["-movflags", "+faststart"],
        )
        try:
            for frame in arr:
                writer.append_data(frame)
        finally:
            writer.close()
    else:
        # GIF frame duration is stored in milliseconds.
        imageio.mimsave(tmp, list(arr), format="GIF", duration=1000.0 / fps, loop=0)
    tmp.replace(path)
    return path


def read_video(path: str | Path) -> np.ndarray:
    """All frames of a video file as ``[T, H, W, 3]`` uint8."""
    import imageio.v2 as imageio

    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path}: video file not found")
    try:
        if path.suffix.lower() == ".gif":
            frames = [np.asarray(f) for f in imageio.mimread(path, memtest=False)]
        else:
            reader = imageio.get_reader(path, format="FFMPEG")
            try:
                frames = [np.asarray(f) for f in reader]
            finally:
                reader.close()
    except (OSError, ValueError, RuntimeError) as err:
        raise UserInputError(
            f"{path}: cannot read as a video ({str(err).splitlines()[0]})"
        ) from None
    out = []
    for f in frames:
        if f.ndim == 2:
            f = np.repeat(f[..., None], 3, axis=-1)
        out.append(f[..., :3])
    if not out:
        raise UserInputError(f"{path}: video has no frames")
    return np.stack(out).astype(np.uint8)


def write_image(image, path: str | Path) -> Path:
    """Write one ``[H, W, 3]`` image (uint8 or float in [0, 1]) as PNG/JPEG."""
    import imageio.v2 as imageio

    path = Path(path)
    arr = to_uint8(image)
    if arr.ndim != 3 or arr.shape[-1] not in (3, 4):
        raise UserInputError(f"{path}: image must be [H, W, 3], got {arr.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    imageio.imwrite(tmp, arr, format=path.suffix.lstrip(".").upper() or "PNG")
    tmp.replace(path)
    return path
