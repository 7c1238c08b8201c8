"""What a user who loads a capture as it is should hear before it is simulated.

A 3DGS capture comes in its capture tool's frame and units, with floaters and, often,
its surroundings. Loaded with ``scene: {source: capture.ply}`` and nothing else, the
shared table capture (``yashica_t4_table.ply``) was simulated as one 57 m body: 2 % of
its splats float up to 30 units from the rest, the grid was fitted around them (cells 12x
coarser than the rest needed), its header's "Vertical axis: y" was not read, and the
whole room fell over as one jelly. Nothing said why. :func:`capture_notes` gives the
one-line warnings that say what was read and what to set:

* the header names a vertical axis (``comment Vertical axis: y``, as Brush writes) other
  than the one simulated, and ``scene.up`` was left out;
* a few splats lie far from the rest (the box of all of them is over
  :data:`FLOATER_RATIO` times the box of the rest): the grid is fitted to all, the
  warning gives the ``scene.crop`` that discards them;
* the body is over :data:`LARGE_SIZE` m across as read (a capture's units are not
  metres): ``scene.scale``.

With a ``scene.region`` only the region is simulated and the rest stays still: none of
these apply. Nothing here changes the scene; the lines go to the summary's warnings.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

__all__ = ["capture_notes", "header_up_axis", "FLOATER_RATIO", "LARGE_SIZE"]

FLOATER_RATIO = 3.0
"""The box of all simulated splats is called floater-dominated when its largest side is
over this many times that of the box holding the central 98 % of them (per axis, the 1st
to 99th percentiles)."""
LARGE_SIZE = 3.0
"""A simulated body over this many metres across (its central 98 %), read from a file (a
capture or a mesh: an STL written in millimetres is 1000x too large), gets a line on its
units."""
_AXIS = re.compile(r"(?:vertical|up)[ _-]*(?:axis|direction)?\s*[:=]\s*([+-]?[xyz])\b", re.I)


def _header_comments(path: Path) -> list[str]:
    """The ``comment`` lines of a PLY header (read up to ``end_header`` only)."""
    out: list[str] = []
    with path.open("rb") as f:
        for _ in range(10000):
            line = f.readline()
            if not line:
                break
            text = line.decode("latin-1").strip()
            if text == "end_header":
                break
            if text.startswith("comment "):
                out.append(text[len("comment ") :])
    return out


def header_up_axis(source: str) -> tuple[str, str] | None:
    """``(axis, comment)``: the vertical axis a .ply header states (``comment Vertical
    axis: y``; ``y``, ``-y``, ...) and the comment that says it; None when it states none
    or the source is not a .ply file."""
    path = Path(str(source)).expanduser()
    if path.suffix.lower() != ".ply" or not path.is_file():
        return None
    for comment in _header_comments(path):
        m = _AXIS.search(comment)
        if m:
            return m.group(1).lower(), comment
    return None


def _fmt(values) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in values) + "]"


def capture_notes(scene_cfg, points: np.ndarray) -> list[str]:
    """Warnings for the scene of ``scene_cfg`` whose simulated splat centres (world frame,
    after the transform, the opacity filter and the crop) are ``points`` [N, 3] m."""
    source = str(scene_cfg.source)
    if source.startswith("builtin:") or getattr(scene_cfg, "region", None) is not None:
        return []
    notes: list[str] = []
    stated = header_up_axis(source)
    given = "up" in scene_cfg.model_fields_set
    if stated is not None and not given and stated[0].lstrip("+") != str(scene_cfg.up):
        axis = stated[0].lstrip("+-")
        notes.append(
            f"scene: the capture's header says '{stated[1]}', and it is simulated with "
            f"{scene_cfg.up} up (`scene.up` left out), so gravity pulls along its "
            f"{scene_cfg.up} axis; set `scene.up: {axis}` or `-{axis}` (the header does not "
            "say which way is up), or the normal of its ground as a vector"
        )
    p = np.asarray(points, dtype=np.float64)
    if p.shape[0] < 50:
        return notes
    lo, hi = np.percentile(p, 1.0, axis=0), np.percentile(p, 99.0, axis=0)
    core = float((hi - lo).max())
    whole = float(np.ptp(p, axis=0).max())
    if core > 0 and whole > FLOATER_RATIO * core:
        margin = 0.1 * (hi - lo) + 1e-3 * core
        clo, chi = lo - margin, hi + margin
        far = int((((p < clo) | (p > chi)).any(axis=1)).sum())
        crop = [v for pair in zip(clo, chi, strict=True) for v in pair]
        notes.append(
            f"scene: {far} of {p.shape[0]} splats ({100 * far / p.shape[0]:.1f} %) lie far "
            f"from the rest (floaters): all of them span {whole:.3g} m, {whole / core:.0f}x "
            f"the {core:.3g} m the central 98 % span, and the simulation grid is fitted to "
            f"all, so its cells are that much coarser; `scene.crop: {_fmt(crop)}` discards "
            "them (or `scene.region` simulates part of the capture and keeps the rest still)"
        )
    if core > LARGE_SIZE:  # (a file: a builtin returned above; an STL in mm is 1000x)
        notes.append(
            f"scene: the body simulated is {core:.3g} m across (the file's units read as "
            "metres, and everything in it simulated as one material); `scene.scale` sets "
            "its size, `scene.region` picks one object of a capture and keeps the rest still"
        )
    return notes
