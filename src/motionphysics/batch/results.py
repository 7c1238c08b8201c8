"""The results table of a sweep, rebuilt from its job directories.

``OUT/results.csv`` and ``OUT/results.html``: one row per job of the current sweep, in
the sweep's job order, with

    job, <one column per axis>, status, message, class, density, param.<name>...,
    metric.<name>..., wall_time_s, attempts, exit_code, video, dir

``param.*`` are the physical (SI) parameters of ``params.json``; ``metric.*`` the
numeric scalars of ``metrics.json`` (nested objects flattened with dots, arrays left
out), so a key added to either file becomes a column without a change here. ``video``
and ``dir`` are relative to OUT, so the folder can be moved or served as it is.

The table is derived, never a source of truth: it is written atomically from what the
job directories hold whenever the runner asks, so a batch killed at any moment leaves
a table that the next run rebuilds. A directory whose ``config_hash`` is not the
current job's (an earlier, different sweep) contributes nothing but ``pending``.
This module reads job directories and writes the two table files; it runs nothing.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from motionphysics.batch.jobs import read_job_state
from motionphysics.batch.sweep import Sweep

__all__ = ["RESULTS_CSV", "RESULTS_HTML", "build_table", "write_results"]

RESULTS_CSV = "results.csv"
RESULTS_HTML = "results.html"
_METRIC_SKIP = {"schema"}


def _flatten_numbers(obj: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for key, value in obj.items():
        name = f"{prefix}{key}"
        if isinstance(value, bool):
            out[name] = value
        elif isinstance(value, (int, float)):
            out[name] = value
        elif isinstance(value, Mapping):
            _flatten_numbers(value, f"{name}.", out)


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    if isinstance(value, (int, str)):
        return str(value)
    return json.dumps(value, ensure_ascii=False)


def build_table(
    sweep: Sweep, running: Iterable[str] = ()
) -> tuple[list[str], list[dict[str, Any]]]:
    """Columns and rows (raw values) of the sweep's table from its job directories.

    ``running`` names jobs in flight right now (shown ``running`` instead of the
    ``interrupted`` their directory would say).
    """
    running = set(running)
    rows: list[dict[str, Any]] = []
    params_cols: list[str] = []
    metric_cols: list[str] = []
    for job in sweep.jobs:
        d = sweep.job_dir(job)
        st = read_job_state(d)
        status = st.status_for(job.config_hash)
        if job.id in running:
            status = "running"
        row: dict[str, Any] = {"job": job.id, **job.values, "status": status}
        rec = st.record or {}
        mine = status != "pending"
        if mine:
            row["message"] = rec.get("message") if status in ("failed", "interrupted") else ""
            p = st.params or {}
            row["class"] = p.get("class")
            row["density"] = p.get("density")
            for name, value in (p.get("params") or {}).items():
                col = f"param.{name}"
                row[col] = value
                if col not in params_cols:
                    params_cols.append(col)
            if status == "complete":
                metrics: dict[str, Any] = {}
                m = _read_metrics(d)
                _flatten_numbers({k: v for k, v in m.items() if k not in _METRIC_SKIP}, "", metrics)
                for name, value in metrics.items():
                    col = f"metric.{name}"
                    row[col] = value
                    if col not in metric_cols:
                        metric_cols.append(col)
                # job.json's wall time is the whole job process; a job killed after its
                # run finished has only the run's own figure.
                row["wall_time_s"] = rec.get("wall_time_s") or p.get("wall_time_s")
            else:
                row["wall_time_s"] = rec.get("wall_time_s")
            row["attempts"] = rec.get("attempts")
            row["exit_code"] = rec.get("exit_code")
            if (d / "video.mp4").is_file() and status == "complete":
                row["video"] = f"jobs/{job.id}/video.mp4"
        row["dir"] = f"jobs/{job.id}"
        rows.append(row)
    columns = [
        "job",
        *sweep.axes,
        "status",
        "message",
        "class",
        "density",
        *params_cols,
        *metric_cols,
        "wall_time_s",
        "attempts",
        "exit_code",
        "video",
        "dir",
    ]
    return columns, rows


def _read_metrics(d: Path) -> dict[str, Any]:
    try:
        data = json.loads((d / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _csv_text(columns: list[str], rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_cell(row.get(c)) for c in columns])
    return buf.getvalue()


_STATUS_COLOUR = {
    "complete": "#d8f5d0",
    "failed": "#fbd3d0",
    "interrupted": "#fdf0c4",
    "running": "#d6e8fb",
    "pending": "#eeeeee",
}


def _html_text(sweep: Sweep, columns: list[str], rows: list[dict[str, Any]]) -> str:
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    summary = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = []
    for r in rows:
        cells = []
        for c in columns:
            v = r.get(c)
            if c == "video" and v:
                cells.append(f'<td><a href="{html.escape(v)}">video</a></td>')
            elif c == "dir":
                report = f"{v}/report.html"
                cells.append(
                    f'<td><a href="{html.escape(v)}/">{html.escape(v)}</a> '
                    f'(<a href="{html.escape(report)}">report</a>)</td>'
                )
            elif c == "status":
                colour = _STATUS_COLOUR.get(str(v), "#ffffff")
                cells.append(f'<td style="background:{colour}">{html.escape(_cell(v))}</td>')
            elif isinstance(v, float) and math.isfinite(v):
                cells.append(f'<td class="num" title="{v!r}">{v:.4g}</td>')
            else:
                cells.append(f"<td>{html.escape(_cell(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    title = html.escape(f"sweep {sweep.name}")
    return (
        "<!doctype html>\n<html><head><meta charset='utf-8'>"
        f"<title>{title}</title>"
        "<style>body{font-family:sans-serif;margin:1.5em}"
        "table{border-collapse:collapse;font-size:13px}"
        "th,td{border:1px solid #ccc;padding:3px 6px;vertical-align:top}"
        "th{background:#f4f4f4;position:sticky;top:0}td.num{text-align:right}</style>"
        "</head><body>\n"
        f"<h1>{title}</h1>\n<p>{html.escape(str(sweep.path))}: {len(rows)} jobs ({html.escape(summary)}); "
        f"<a href='{RESULTS_CSV}'>{RESULTS_CSV}</a></p>\n"
        f"<table><thead><tr>{head}</tr></thead><tbody>\n" + "\n".join(body) + "\n</tbody></table>\n"
        "</body></html>\n"
    )


def write_results(sweep: Sweep, running: Iterable[str] = ()) -> list[dict[str, Any]]:
    """Rebuild ``results.csv`` and ``results.html`` in the sweep's folder; returns the rows."""
    from motionphysics.io.rundir import atomic_write

    columns, rows = build_table(sweep, running)
    sweep.out.mkdir(parents=True, exist_ok=True)
    for name, text in (
        (RESULTS_CSV, _csv_text(columns, rows)),
        (RESULTS_HTML, _html_text(sweep, columns, rows)),
    ):
        with atomic_write(sweep.out / name, "wb") as f:
            f.write(text.encode("utf-8"))
    return rows
