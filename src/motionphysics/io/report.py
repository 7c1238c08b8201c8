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

__all__ = [
    "render_report",
    "write_report",
    "physical_rows",
    "optimisation_section_html",
    "svg_curve",
    "UNITS",
]

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
    zeta = osc.get("damping_ratio")  # null with the reason when there is no free decay
    rows.append(
        ("extent damping ratio", zeta if zeta is not None else osc.get("damping_reason"), "–")
    )
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
    sections: Sequence[str] = (),
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
    if params.get("objects"):
        out += _objects_table(params["objects"], e)
    cls = params.get("class", "?")
    prov = params.get("provenance", {}) or {}
    if not params.get("objects"):
        out.append(
            f"<p>Class <b>{e(str(cls))}</b>; estimated by <b>{e(str(prov.get('backend', '?')))}</b>"
            + (" (class set by the config)" if prov.get("class_override") else "")
            + ".</p>"
        )
    phys = (
        {}
        if params.get("objects")
        else {"density": params.get("density"), **(params.get("params") or {})}
    )
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
    simctx = dict(params.get("sim_context") or {})
    changes = simctx.pop("visible_changes", None) or []
    for line in changes:
        out.append(f"<p class='warn'><b>Visible change:</b> {e(str(line))}</p>")
    if simctx:
        items = ", ".join(f"{e(k)} = {_fmt(v)}" for k, v in simctx.items())
        out.append(f"<p class='muted'>Simulation: {items}</p>")

    if video:
        out.append("<h2>Simulation</h2>")
        if (run_dir / video).exists():
            out.append(f"<video src='{e(video)}' controls loop autoplay muted playsinline></video>")
        else:
            out.append(f"<p class='muted'>No video ({e(video)} missing).</p>")
    # a run without refinement: the motion the prompt asks for beside the one simulated
    # (a refined run shows it in the optimisation section, before and after)
    plain = {} if params.get("optimise") else (params.get("metrics") or {}).get("motion") or {}
    if plain.get("lines"):
        out.append("<h3>Motion asked for and simulated</h3>")
        out.append("<pre>" + e("\n".join(plain["lines"])) + "</pre>")

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
    out.extend(sections)  # extra HTML fragments (the optimisation section)
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _objects_table(objects, e) -> list[str]:
    """One row per object of a scene of several: name, class, backend, density, parameters."""
    rows = [
        "<table><tr><th>object</th><th>class</th><th>from</th><th>particles</th>"
        "<th>density (kg/m³)</th><th>parameters (SI)</th><th>simulation values</th></tr>"
    ]
    for o in objects:
        prov = o.get("provenance") or {}
        phys = ", ".join(f"{e(k)} = {_fmt(v)}" for k, v in (o.get("params") or {}).items())
        sim = ", ".join(f"{e(k)} = {_fmt(v)}" for k, v in (o.get("sim") or {}).items())
        rows.append(
            f"<tr><td>{e(str(o.get('name')))}</td><td>{e(str(o.get('class')))}</td>"
            f"<td>{e(str(prov.get('backend', '?')))}</td><td class='num'>{o.get('particles')}</td>"
            f"<td class='num'>{_fmt(o.get('density'))}</td><td>{phys}</td><td>{sim}</td></tr>"
        )
    rows.append("</table>")
    return rows


def write_report(rundir, params: Mapping[str, Any], **kwargs: Any) -> Path:
    """Write ``report.html`` into a :class:`~motionphysics.io.rundir.RunDirectory`."""
    text = render_report(rundir.path, params, **kwargs)
    return rundir.write_text("report.html", text)


# --------------------------------------------------------------------------------------
# optimised runs: initial vs refined video, loss and parameter curves, the viewer
# --------------------------------------------------------------------------------------
_SECTION_CSS = (
    ".pair{display:flex;gap:1em;flex-wrap:wrap} .pair figure{flex:1 1 300px;margin:0}"
    " .pair video{width:100%} .curves{display:flex;flex-wrap:wrap;gap:.8em}"
    " .curves svg{border:1px solid #eee;background:#fff} pre{background:#f6f6f6;padding:.6em 1em}"
)


def svg_curve(
    xs: Sequence[float],
    ys: Sequence[float],
    title: str,
    *,
    xlabel: str = "iteration",
    band: tuple[float, float] | None = None,
    width: int = 300,
    height: int = 180,
) -> str:
    """An inline SVG line chart of ``ys`` over ``xs`` (no scripts, no network).

    Non-finite points are skipped. The y axis is logarithmic when every value (and the
    band) is positive and they span more than a factor of 100. ``band`` = (low, high)
    shades an allowed range (clipped to the plotted span). Returns ``""`` when there is
    no finite point.
    """
    import math

    pts = [
        (float(x), float(y))
        for x, y in zip(xs, ys, strict=False)
        if x is not None and y is not None and math.isfinite(float(x)) and math.isfinite(float(y))
    ]
    if not pts:
        return ""
    vals = [y for _, y in pts]
    lo_v, hi_v = min(vals), max(vals)
    log = lo_v > 0 and hi_v / lo_v > 100 and (band is None or band[0] > 0)
    f = (lambda v: math.log10(v)) if log else (lambda v: v)
    y0, y1 = f(lo_v), f(hi_v)
    if y1 - y0 < 1e-12 * max(1.0, abs(y0)):
        y0, y1 = y0 - 0.5 * max(abs(y0), 1e-12), y1 + 0.5 * max(abs(y1), 1e-12)
    pad = 0.08 * (y1 - y0)
    y0, y1 = y0 - pad, y1 + pad
    x0, x1 = min(x for x, _ in pts), max(x for x, _ in pts)
    if x1 == x0:
        x0, x1 = x0 - 0.5, x1 + 0.5
    left, right, top, bottom = 66, 10, 22, 28
    pw, ph = width - left - right, height - top - bottom

    def px(x):
        return left + (x - x0) / (x1 - x0) * pw

    def py(y):
        return top + (1.0 - (f(y) - y0) / (y1 - y0)) * ph

    e = html.escape
    out = [
        f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' "
        f"role='img' aria-label='{e(title)}'>",
        f"<text x='{width / 2:.0f}' y='15' text-anchor='middle' font-size='12'>{e(title)}</text>",
    ]
    if band is not None:
        b_lo, b_hi = (max(v, 10**y0 if log else y0) for v in band)
        b_lo, b_hi = (min(v, 10**y1 if log else y1) for v in (b_lo, b_hi))
        if b_hi > b_lo:
            out.append(
                f"<rect x='{left}' y='{py(b_hi):.1f}' width='{pw}' height='{py(b_lo) - py(b_hi):.1f}' "
                "fill='#cfe8d6' opacity='0.6'><title>allowed range</title></rect>"
            )
    out.append(f"<rect x='{left}' y='{top}' width='{pw}' height='{ph}' fill='none' stroke='#bbb'/>")
    path = " ".join(f"{px(x):.1f},{py(y):.1f}" for x, y in pts)
    out.append(f"<polyline points='{path}' fill='none' stroke='#2a6' stroke-width='1.8'/>")
    for y in (lo_v, hi_v):
        out.append(
            f"<text x='{left - 4}' y='{py(y) + 4:.1f}' text-anchor='end' font-size='10'>{_fmt(y)}</text>"
        )
    out.append(
        f"<text x='{left}' y='{height - 8}' font-size='10'>{_fmt(x0)}</text>"
        f"<text x='{left + pw}' y='{height - 8}' text-anchor='end' font-size='10'>{_fmt(x1)}</text>"
        f"<text x='{left + pw / 2:.0f}' y='{height - 8}' text-anchor='middle' font-size='10'>"
        f"{e(xlabel)}{' (log y)' if log else ''}</text>"
    )
    out.append("</svg>")
    return "".join(out)


def optimisation_section_html(
    run_dir: str | Path,
    params: Mapping[str, Any],
    *,
    history: Sequence[Mapping[str, Any]] | None = None,
    initial_video: str | None = "video_initial.mp4",
    refined_video: str = "video.mp4",
    ranges: Mapping[str, tuple[float, float]] | None = None,
    viewer_command: str | None = None,
) -> str:
    """HTML fragment for an optimised run, to place in ``report.html``'s body.

    Holds: the initial and refined videos side by side (relative paths inside
    ``run_dir``; a missing file is said, not hidden), the loss curve and one curve per
    optimised parameter (inline SVG from ``history``, default ``params["history"]``;
    records as in ``log.jsonl``: ``iteration``, ``loss``, ``params`` in SI), each
    parameter over its allowed ``ranges`` band when given, and a section
    ``id='viewer'`` on how to open the run in ``motionphysics view`` (linked from the
    top of the fragment). Returns ``""`` when there is no history (not optimised).
    """
    run_dir = Path(run_dir)
    e = html.escape
    from motionphysics.io.object_params import flat_params

    records = list(history if history is not None else params.get("history") or [])
    if not records:
        return ""
    # several objects: each object's values as OBJECT.PARAM curves
    records = [{**r, "params": flat_params(r.get("params") or {})} for r in records]
    out = [f"<style>{_SECTION_CSS}</style>", "<h2 id='optimisation'>Optimisation</h2>"]
    opt = params.get("optimise") or {}
    stop = opt.get("stop_reason")
    out.append(
        f"<p>{len(records)} iterations"
        + (f"; stopped: {e(str(stop))}" if stop else "")
        + ". <a href='#viewer'>Open this run in the viewer</a> to see it from any side.</p>"
    )
    motion = opt.get("motion") or {}
    if motion.get("lines"):
        out.append("<h3>Motion asked for and simulated</h3>")
        out.append("<pre>" + e("\n".join(motion["lines"])) + "</pre>")
    out.append("<div class='pair'>")
    for label, rel in (
        ("initial parameters", initial_video),
        ("refined parameters", refined_video),
    ):
        out.append(f"<figure><figcaption>{e(label)}</figcaption>")
        if rel and (run_dir / rel).is_file():
            out.append(f"<video src='{e(rel)}' controls loop autoplay muted playsinline></video>")
        else:
            out.append(
                f"<p class='muted'>No video ({e(str(rel)) if rel else 'not rendered'} missing).</p>"
            )
        out.append("</figure>")
    out.append("</div>")

    its = [r.get("iteration", i) for i, r in enumerate(records)]
    curves = [svg_curve(its, [r.get("loss") for r in records], "loss")]
    names: list[str] = []
    for r in records:
        for k in r.get("params") or {}:
            if k not in names:
                names.append(k)
    for k in names:
        unit = UNITS.get(k.rpartition(".")[2], "")
        title = f"{k} [{unit}]" if unit and unit != "–" else k
        ys = [(r.get("params") or {}).get(k) for r in records]
        curves.append(svg_curve(its, ys, title, band=(ranges or {}).get(k)))
    curves = [c for c in curves if c]
    if curves:
        out.append("<h3>Loss and parameters per iteration</h3><div class='curves'>")
        out.extend(curves)
        out.append("</div>")

    cmd = viewer_command or f"motionphysics view {run_dir}"
    out.append("<h2 id='viewer'>Open in the viewer</h2>")
    out.append(
        "<p>The viewer shows the deformed splats of every frame from any camera, with the "
        "ground and colliders, a timeline and this run's material, curves and metrics. "
        "Run</p>"
        f"<pre>{e(cmd)}</pre>"
        "<p>and open the address it prints (http://127.0.0.1:8080 by default; "
        "<code>--port N</code> picks another, <code>--frame K</code> the first frame shown, "
        "several run directories can be given to switch between them). Ctrl-C stops it.</p>"
    )
    return "\n".join(out) + "\n"
