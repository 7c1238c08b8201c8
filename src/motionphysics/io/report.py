"""``report.html``: a self-contained page summarising one run.

It shows the prompt, the material (class, density and every parameter in SI units
beside its simulation value, with where each came from), the video, the plots, the
key physical metrics and the time each stage took. Everything it links is a relative
path inside the run directory (video, PNGs) or inlined; it loads nothing from the
network, so the folder can be copied or zipped and opened anywhere.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["render_report", "write_report", "physical_rows", "UNITS"]

UNITS = {
    "density": "kg/m³",
    "E": "Pa",
    "nu": "–",
    "tau_Y": "Pa",
    "eta": "–",
    "theta_fric": "°",
    "mu": "Pa·s",
    "kappa": "Pa",
    "n": "–",
}

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:980px;color:#222;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em} h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
.prompt{font-size:1.15em;font-style:italic;background:#f6f6f6;padding:.6em 1em;border-left:4px solid #4a7}
table{border-collapse:collapse;margin:.5em 0} td,th{border:1px solid #ddd;padding:.3em .7em;text-align:left}
th{background:#f3f3f3} td.num{text-align:right;font-variant-numeric:tabular-nums}
.muted{color:#777;font-size:.9em} .partial{background:#fee;border:1px solid #c66;padding:.5em 1em}
.plots img{max-width:100%;margin:.4em 0;border:1px solid #eee}
video{max-width:100%;border:1px solid #ddd;background:#000}
"""


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if v == 0:
            return "0"
        a = abs(v)
        return f"{v:.4g}" if 1e-3 <= a < 1e5 else f"{v:.3e}"
    return html.escape(str(v))


def physical_rows(metrics: Mapping[str, Any]) -> list[tuple[str, Any, str]]:
    """(label, value, unit) rows of the report's "Physical diagnostics" table."""
    ext = metrics.get("final_extent_ratio", metrics.get("final_height_ratio"))
    rows: list[tuple[str, Any, str]] = [
        ("vertical extent, final / initial", ext, "–"),
        (
            "centroid height above floor, final",
            metrics.get("final_centroid_height_above_floor"),
            "m",
        ),
        ("rebound ratio (centroid rise / fall)", metrics.get("rebound_ratio"), "–"),
        ("spread, final / initial", metrics.get("spread_ratio"), "–"),
        ("max displacement", metrics.get("max_displacement"), "m"),
        ("max speed", metrics.get("max_speed"), "m/s"),
        ("max kinetic energy", metrics.get("max_kinetic_energy"), "J"),
        ("centroid drop", metrics.get("centroid_drop"), "m"),
    ]
    rows = [r for r in rows if r[1] is not None]
    vr = metrics.get("volume_ratio") or {}
    rows += [
        ("volume ratio det F, min", vr.get("overall_min"), "–"),
        ("volume ratio det F, max", vr.get("overall_max"), "–"),
    ]
    osc = metrics.get("height_oscillation") or {}
    f = osc.get("frequency_hz")
    rows.append(
        (
            "extent oscillation",
            f if f is not None else osc.get("frequency_reason") or None,
            "Hz" if f else "",
        )
    )
    rows.append(("extent damping ratio", osc.get("damping_ratio"), "–"))
    return rows


def _img_src(run_dir: Path, rel: str, inline: bool) -> str:
    if not inline:
        return html.escape(rel)
    data = (run_dir / rel).read_bytes()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def render_report(
    run_dir: str | Path,
    params: Mapping[str, Any],
    *,
    prompt: str,
    timings: Mapping[str, float] | None = None,
    metrics: Mapping[str, Any] | None = None,
    video: str | None = "video.mp4",
    plots: Sequence[str] = (),
    inline_images: bool = False,
    title: str = "motionphysics run",
) -> str:
    """HTML text of the report.

    ``params`` is the content of ``params.json``; ``plots`` are PNG paths relative to
    ``run_dir`` (inlined as base64 when ``inline_images``); ``video`` is relative too.
    """
    run_dir = Path(run_dir)
    e = html.escape
    out: list[str] = [
        "<!DOCTYPE html>",
        "<html lang='en'><head><meta charset='utf-8'>",
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        f"<div class='prompt'>{e(prompt)}</div>",
    ]
    if params.get("partial", False):
        out.append(
            "<p class='partial'>This run did not finish (partial: true); "
            f"it stopped during “{e(str(params.get('stage', '?')))}”.</p>"
        )

    out.append("<h2>Material</h2>")
    cls = params.get("class", "?")
    prov = params.get("provenance", {}) or {}
    out.append(
        f"<p>Class <b>{e(str(cls))}</b>; estimated by <b>{e(str(prov.get('backend', '?')))}</b>"
        + (" (class set by the config)" if prov.get("class_override") else "")
        + ".</p>"
    )
    phys = {"density": params.get("density"), **(params.get("params") or {})}
    sim = params.get("sim") or {}
    sources = prov.get("sources") or {}
    out.append(
        "<table><tr><th>parameter</th><th>physical (SI)</th><th>unit</th>"
        "<th>simulation value</th><th>from</th></tr>"
    )
    for name, value in phys.items():
        out.append(
            f"<tr><td>{e(name)}</td><td class='num'>{_fmt(value)}</td><td>{e(UNITS.get(name, ''))}</td>"
            f"<td class='num'>{_fmt(sim.get(name))}</td><td>{e(str(sources.get(name, '')))}</td></tr>"
        )
    out.append("</table>")
    clamps = prov.get("clamps") or []
    if clamps:
        items = "; ".join(
            f"{e(str(c.get('field')))}: {_fmt(c.get('original'))} → {_fmt(c.get('clamped'))}"
            for c in clamps
        )
        out.append(f"<p class='muted'>Clamped into the handbook range: {items}</p>")
    simctx = params.get("sim_context") or {}
    if simctx:
        items = ", ".join(f"{e(k)} = {_fmt(v)}" for k, v in simctx.items())
        out.append(f"<p class='muted'>Simulation: {items}</p>")

    if video:
        out.append("<h2>Simulation</h2>")
        if (run_dir / video).exists():
            out.append(f"<video src='{e(video)}' controls loop autoplay muted playsinline></video>")
        else:
            out.append(f"<p class='muted'>No video ({e(video)} missing).</p>")

    if plots:
        out.append("<h2>Plots</h2><div class='plots'>")
        for rel in plots:
            if (run_dir / rel).is_file():
                out.append(
                    f"<figure><img src='{_img_src(run_dir, rel, inline_images)}' alt='{e(rel)}'>"
                    f"<figcaption class='muted'>{e(rel)}</figcaption></figure>"
                )
        out.append("</div>")

    if metrics:
        out.append(
            "<h2>Physical diagnostics</h2><table><tr><th>quantity</th><th>value</th><th>unit</th></tr>"
        )
        for k, v, unit in physical_rows(metrics):
            out.append(f"<tr><td>{e(k)}</td><td class='num'>{_fmt(v)}</td><td>{e(unit)}</td></tr>")
        out.append("</table>")

    history = params.get("history") or []
    if history:
        out.append(
            f"<p class='muted'>Optimised over {len(history)} iterations (see log.jsonl).</p>"
        )

    if timings:
        total = sum(timings.values())
        out.append("<h2>Timings</h2><table><tr><th>stage</th><th>seconds</th></tr>")
        for k, v in timings.items():
            out.append(f"<tr><td>{e(k)}</td><td class='num'>{v:.2f}</td></tr>")
        out.append(f"<tr><th>total</th><th class='num'>{total:.2f}</th></tr></table>")

    versions = params.get("versions") or {}
    if versions:
        out.append(
            "<p class='muted'>"
            + ", ".join(f"{e(k)} {e(str(v))}" for k, v in versions.items())
            + "</p>"
        )
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def write_report(rundir, params: Mapping[str, Any], **kwargs: Any) -> Path:
    """Write ``report.html`` into a :class:`~motionphysics.io.rundir.RunDirectory`."""
    text = render_report(rundir.path, params, **kwargs)
    return rundir.write_text("report.html", text)
