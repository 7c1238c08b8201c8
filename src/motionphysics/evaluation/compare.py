"""Comparison of several runs: a labelled video grid and a Table-2 style table.

Reads each run through its files (``metrics.evaluate``); writes only into the output
folder. The table has one column per run and the paper's rows (class, parameters,
OC, CLIPSIM, ECMS, optimisation time) plus ECMS's three terms and motion adherence.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["compare_runs", "table_rows", "markdown_table", "html_table", "video_grid"]

OUTPUTS = ("compare.mp4", "compare.md", "compare.html", "compare.json")


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool) or isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        a = abs(v)
        return "0" if v == 0 else (f"{v:.4g}" if 1e-3 <= a < 1e5 else f"{v:.3e}")
    return str(v)


def table_rows(entries: list[dict[str, Any]]) -> list[tuple[str, list[str]]]:
    """[(row label, [cell per run])] in the paper's Table 2 order."""
    from motionphysics.io.report import UNITS

    rows: list[tuple[str, list[str]]] = [
        ("class", [str(e["params"].get("class", "–")) for e in entries])
    ]
    names: list[str] = []
    for e in entries:
        for k in ["density", *((e["params"].get("params") or {}).keys())]:
            if k not in names:
                names.append(k)
    for k in names:
        cells = []
        for e in entries:
            p = e["params"]
            cells.append(
                _fmt(p.get("density") if k == "density" else (p.get("params") or {}).get(k))
            )
        unit = UNITS.get(k, "")
        rows.append((f"{k} [{unit}]" if unit and unit != "–" else k, cells))

    def metric(key, scale=1.0):
        out = []
        for e in entries:
            v = e["metrics"].get(key)
            out.append(_fmt(v * scale) if isinstance(v, (int, float)) else "–")
        return out

    rows.append(("OC ×10⁻² ↑", metric("oc", 100.0)))
    rows.append(("CLIPSIM ×10⁻² ↑", metric("clipsim", 100.0)))
    rows.append(("ECMS ↓", metric("ecms")))
    for t in ("motion", "temporal", "spatial"):
        rows.append(
            (
                f"  ECMS {t} sum",
                [_fmt((e["metrics"].get("ecms_terms") or {}).get(t)) for e in entries],
            )
        )
    rows.append(
        (
            "motion adherence ↑",
            [_fmt((e["metrics"].get("motion_adherence") or {}).get("score")) for e in entries],
        )
    )
    rows.append(("optimisation time [s]", metric("optimisation_time_s")))
    return rows


def markdown_table(labels: list[str], rows) -> str:
    lines = ["| | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows]
    return "\n".join(lines) + "\n"


def html_table(labels: list[str], rows, video: str | None) -> str:
    e = html.escape
    out = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>motionphysics compare</title>",
        "<style>body{font-family:system-ui,sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:.3em .7em}td{text-align:right}th{background:#f3f3f3}"
        "video{max-width:100%}</style></head><body><h1>Comparison</h1>",
    ]
    if video:
        out.append(f"<video src='{e(video)}' controls loop autoplay muted playsinline></video>")
    out.append("<table><tr><th></th>" + "".join(f"<th>{e(lab)}</th>" for lab in labels) + "</tr>")
    for name, cells in rows:
        out.append(f"<tr><th>{e(name)}</th>" + "".join(f"<td>{e(c)}</td>" for c in cells) + "</tr>")
    out.append("</table></body></html>")
    return "\n".join(out) + "\n"


def _label(img: np.ndarray, text: str) -> np.ndarray:
    """A white strip with ``text`` above ``img`` [H, W, 3] uint8."""
    from PIL import Image, ImageDraw

    h, w = img.shape[:2]
    strip = max(12, h // 12)
    canvas = Image.new("RGB", (w, h + strip), (255, 255, 255))
    canvas.paste(Image.fromarray(img), (0, strip))
    ImageDraw.Draw(canvas).text((2, 1), text[: max(4, w // 6)], fill=(0, 0, 0))
    return np.asarray(canvas)


def video_grid(videos: list[np.ndarray], labels: list[str]) -> np.ndarray:
    """Labelled grid [T, H', W', 3] uint8 of videos (resized to the first one's height)."""
    from PIL import Image

    h = int(videos[0].shape[1])
    T = max(v.shape[0] for v in videos)
    tiles = []
    for v, lab in zip(videos, labels, strict=True):
        if v.shape[1] != h:
            w = int(round(v.shape[2] * h / v.shape[1]))
            v = np.stack([np.asarray(Image.fromarray(f).resize((w, h))) for f in v])
        v = np.concatenate([v, np.repeat(v[-1:], T - v.shape[0], 0)]) if v.shape[0] < T else v
        tiles.append(np.stack([_label(f, lab) for f in v]))
    cols = min(len(tiles), 4)
    rows = int(math.ceil(len(tiles) / cols))
    th = tiles[0].shape[1]
    widths = [t.shape[2] for t in tiles]
    tw = max(widths)
    grid = np.full((T, rows * th, cols * tw, 3), 255, np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, cols)
        grid[:, r * th : (r + 1) * th, c * tw : c * tw + t.shape[2]] = t
    return grid


def compare_runs(
    run_dirs: list[str | Path],
    out: str | Path,
    *,
    labels: list[str] | None = None,
    force: bool = False,
) -> Path:
    """Write compare.{mp4,md,html,json} into ``out``; returns ``out``."""
    from motionphysics.evaluation.evaluate import evaluate_run, read_run_files
    from motionphysics.io.rundir import to_json_text
    from motionphysics.io.video import read_video, write_video

    run_dirs = [Path(p) for p in run_dirs]
    if labels is not None and len(labels) != len(run_dirs):
        raise UserInputError(
            f"--labels: expected {len(run_dirs)} labels (one per run), got {len(labels)}"
        )
    labels = labels or [p.name or str(p) for p in run_dirs]
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserInputError(f"--out {out}: exists and is not a directory")
    if out.is_dir() and any((out / n).exists() for n in OUTPUTS) and not force:
        raise UserInputError(f"--out {out}: holds a comparison; pass --force to overwrite it")
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for p in run_dirs:
        files = read_run_files(p)
        m = {}
        mp = p / "metrics.json"
        if mp.is_file():
            try:
                m = json.loads(mp.read_text())
            except ValueError:
                m = {}
        # evaluated with every metric, and against the run's own prompt (not an --prompt)
        if "ecms" not in m or "motion_adherence" not in m or m.get("prompt_source") == "--prompt":
            m = evaluate_run(p, write=False)
        entries.append(
            {"path": p, "params": files["params"], "metrics": m, "video": files["video_path"]}
        )
    rows = table_rows(entries)
    videos = [read_video(e["video"]) for e in entries if e["video"] is not None]
    video_name = None
    if len(videos) == len(entries):
        grid = video_grid(videos, labels)
        fd = entries[0]["params"].get("sim_context", {}).get("frame_dt") or 0.04
        write_video(grid, out / "compare.mp4", fps=max(1.0, min(60.0, 1.0 / float(fd))))
        video_name = "compare.mp4"
    (out / "compare.md").write_text(markdown_table(labels, rows))
    (out / "compare.html").write_text(html_table(labels, rows, video_name))
    (out / "compare.json").write_text(
        to_json_text({"labels": labels, "runs": [str(e["path"]) for e in entries], "rows": rows})
    )
    return out
