"""PNG plots of a run: loss and parameter curves, and the paper's space-time slices.

Generic on purpose: the optimiser, ``fit`` and the pipeline all call these with plain
records. Matplotlib runs with the Agg backend (no display, no network) and every
file is written atomically (temporary name, then ``os.replace``).

Record format (one per optimisation iteration, the lines of ``log.jsonl``)::

    {"iteration": int, "loss": float, "params": {"E": float, ...}, ...}

``params`` holds physical values (SI). Records without a ``loss`` or a given
parameter are skipped for that curve.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_loss", "plot_params", "space_time_slice", "slice_image", "plot_series"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path, dpi: int = 100) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        _pyplot().close(fig)
    return path


def _iterations(records: Sequence[Mapping[str, Any]]) -> list[int]:
    return [int(r.get("iteration", i)) for i, r in enumerate(records)]


def plot_loss(records: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Loss per iteration (log y-axis when all losses are positive).

    Keys of a record starting with ``loss_`` (components) are drawn as thin extra
    curves. Raises ``ValueError`` when no record has a finite loss.
    """
    plt = _pyplot()
    its = _iterations(records)
    xs, ys = [], []
    for it, r in zip(its, records, strict=True):
        v = r.get("loss")
        if v is not None and math.isfinite(float(v)):
            xs.append(it)
            ys.append(float(v))
    if not ys:
        raise ValueError("plot_loss: no record has a finite 'loss'")
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(xs, ys, "o-", color="C0", ms=3, label="loss")
    comps = sorted({k for r in records for k in r if k.startswith("loss_")})
    for i, k in enumerate(comps):
        cx = [it for it, r in zip(its, records, strict=True) if r.get(k) is not None]
        cy = [float(r[k]) for r in records if r.get(k) is not None]
        ax.plot(cx, cy, "-", lw=1, color=f"C{i + 1}", label=k)
    if all(y > 0 for y in ys):
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.grid(alpha=0.3)
    if comps:
        ax.legend(fontsize=8)
    return _save(fig, path)


def plot_params(
    records: Sequence[Mapping[str, Any]],
    ranges: Mapping[str, tuple[float, float]] | None,
    path: str | Path,
) -> Path:
    """One panel per parameter: its value per iteration, with its allowed range shaded.

    ``ranges`` maps a parameter name to its physical ``(low, high)`` (SI); the panel
    uses a log y-axis when the range spans more than a factor of 100. Parameters are
    taken from ``record["params"]``. Raises ``ValueError`` when there is nothing to plot.
    """
    plt = _pyplot()
    ranges = dict(ranges or {})
    its = _iterations(records)
    names: list[str] = []
    for r in records:
        for k in r.get("params") or {}:
            if k not in names:
                names.append(k)
    if not names:
        raise ValueError("plot_params: no record has 'params'")
    n = len(names)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 2.6 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        xs = [it for it, r in zip(its, records, strict=True) if name in (r.get("params") or {})]
        ys = [float(r["params"][name]) for r in records if name in (r.get("params") or {})]
        ax.plot(xs, ys, "o-", ms=3, color="C0")
        if name in ranges:
            lo, hi = (float(v) for v in ranges[name])
            ax.axhspan(lo, hi, color="C2", alpha=0.12, label="range")
            ax.axhline(lo, color="C2", lw=0.8)
            ax.axhline(hi, color="C2", lw=0.8)
            if lo > 0 and hi / lo > 100:
                ax.set_yscale("log")
        elif ys and min(ys) > 0 and max(ys) / min(ys) > 100:
            ax.set_yscale("log")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("iteration", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    return _save(fig, path)


def slice_image(frames: np.ndarray, axis: str = "row", index: int | None = None) -> np.ndarray:
    """The space-time slice of a video as an array.

    Parameters
    ----------
    frames: [T, H, W, 3] uint8 or float in [0, 1]
        The rendered video.
    axis:
        ``"row"``: a horizontal line of pixels (row ``index``) -> image [T, W, 3];
        ``"col"``: a vertical line (column ``index``) -> image [T, H, 3], the column
        laid along the x-axis (top of the frame on the left).
    index:
        Pixel row/column; ``None`` picks the centre.

    Returns
    -------
    [T, L, 3] uint8: time runs down the y-axis (frame 0 at the top), as in the paper.
    """
    a = np.asarray(frames)
    if a.ndim != 4 or a.shape[-1] not in (3, 4):
        raise ValueError(f"frames must be [T, H, W, 3], got {a.shape}")
    if a.dtype != np.uint8:
        a = (np.clip(a.astype(np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    a = a[..., :3]
    _, H, W, _ = a.shape
    if axis == "row":
        i = H // 2 if index is None else int(index)
        if not 0 <= i < H:
            raise ValueError(f"row index {i} outside [0, {H})")
        return np.ascontiguousarray(a[:, i, :, :])
    if axis == "col":
        i = W // 2 if index is None else int(index)
        if not 0 <= i < W:
            raise ValueError(f"column index {i} outside [0, {W})")
        return np.ascontiguousarray(a[:, :, i, :])
    raise ValueError(f"axis must be 'row' or 'col', got {axis!r}")


def space_time_slice(
    frames: np.ndarray,
    path: str | Path,
    axis: str = "row",
    index: int | None = None,
    frame_dt: float | None = None,
    title: str | None = None,
) -> np.ndarray:
    """Save the space-time slice of ``frames`` (see :func:`slice_image`) as a PNG.

    The figure shows the first frame with the sampled line in red beside the slice
    (time on the y-axis, in seconds when ``frame_dt`` is given). Returns the slice
    ``[T, L, 3] uint8``.
    """
    plt = _pyplot()
    sl = slice_image(frames, axis, index)
    a = np.asarray(frames)
    first = a[0] if a.dtype == np.uint8 else np.clip(a[0], 0, 1)
    T, H, W = a.shape[0], a.shape[1], a.shape[2]
    i = (H // 2 if axis == "row" else W // 2) if index is None else int(index)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(7.5, 3.6), gridspec_kw={"width_ratios": [1, 1.3]})
    ax0.imshow(first[..., :3])
    if axis == "row":
        ax0.axhline(i, color="red", lw=1.2)
    else:
        ax0.axvline(i, color="red", lw=1.2)
    ax0.set_title("frame 0", fontsize=9)
    ax0.axis("off")
    t_end = (T - 1) * frame_dt if frame_dt else T - 1
    ax1.imshow(sl, aspect="auto", interpolation="nearest", extent=(0, sl.shape[1], t_end, 0))
    ax1.set_xlabel("pixel along the red line", fontsize=8)
    ax1.set_ylabel("time [s]" if frame_dt else "frame", fontsize=8)
    ax1.set_title(title or f"space-time slice ({axis} {i})", fontsize=9)
    fig.tight_layout()
    _save(fig, path)
    return sl


def plot_series(
    series: Mapping[str, Sequence[float]],
    t: Sequence[float],
    path: str | Path,
    ylabel: str = "",
    title: str = "",
) -> Path:
    """Curves over time on one axis (e.g. energies per frame). ``t`` [T] seconds."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    tt = np.asarray(t, dtype=np.float64)
    for i, (name, ys) in enumerate(series.items()):
        y = np.asarray(ys, dtype=np.float64)
        ax.plot(tt[: len(y)], y, "-", color=f"C{i}", label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)
