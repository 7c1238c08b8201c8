"""report.html: contains the prompt, material table, video, plots and timings; no network."""

from __future__ import annotations

import re

from motionphysics.io.report import render_report, write_report
from motionphysics.io.rundir import RunDirectory

PARAMS = {
    "class": "elastic",
    "density": 1100.0,
    "params": {"E": 2.0e6, "nu": 0.42},
    "sim": {"E": 1.5e5, "nu": 0.42, "density": 1100.0},
    "provenance": {
        "backend": "kb",
        "sources": {"E": "kb", "nu": "config"},
        "clamps": [{"field": "E", "original": 1e13, "clamped": 4e11}],
    },
    "partial": False,
}


def test_report_contents(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.write_bytes("plots/a.png", b"\x89PNG fake")
    rd.write_bytes("video.mp4", b"x")
    p = write_report(
        rd,
        PARAMS,
        prompt="A <rubber> duck",
        timings={"simulate": 1.5},
        metrics={"final_height_ratio": 0.9},
        plots=["plots/a.png", "plots/missing.png"],
    )
    text = p.read_text()
    assert "A &lt;rubber&gt; duck" in text
    assert "elastic" in text and "1.500e+05" in text and "config" in text
    assert "src='video.mp4'" in text and "plots/a.png" in text and "missing.png" not in text
    assert "simulate" in text and "1.50" in text and "4.000e+11" in text
    assert not re.search(r"(src|href)=['\"]?(https?:)?//", text)


def test_report_inline_and_partial(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.write_bytes("plots/a.png", b"\x89PNG fake")
    text = render_report(
        rd.path,
        {**PARAMS, "partial": True, "stage": "simulate"},
        prompt="p",
        plots=["plots/a.png"],
        inline_images=True,
        video=None,
    )
    assert "data:image/png;base64," in text
    assert "did not finish" in text and "simulate" in text


def _history(n=6):
    return [
        {"iteration": i, "loss": 2.0 * 0.5**i, "params": {"E": 1e5 * (1 + i), "nu": 0.3 + 0.01 * i}}
        for i in range(n)
    ]


def test_optimisation_section(tmp_path):
    from motionphysics.io.report import optimisation_section_html

    rd = RunDirectory(tmp_path / "r")
    rd.write_bytes("video.mp4", b"x")
    rd.write_bytes("video_initial.mp4", b"x")
    params = {**PARAMS, "history": _history(), "optimise": {"stop_reason": "iterations"}}
    text = optimisation_section_html(rd.path, params, ranges={"E": (1e4, 1e9)})
    # Both videos, side by side in one row.
    pair = text[text.index("<div class='pair'>") :]
    assert pair.index("video_initial.mp4") < pair.index("src='video.mp4'") < pair.index("</div>")
    # One curve for the loss and one per parameter, drawn from the history.
    assert text.count("<svg") == 3 and "aria-label='loss'" in text and "E [Pa]" in text
    loss_svg = text[text.index("aria-label='loss'") :]
    line = loss_svg[loss_svg.index("points='") + 8 :]
    pts = [tuple(map(float, p.split(","))) for p in line[: line.index("'")].split()]
    assert len(pts) == 6
    xs, ys = zip(*pts, strict=True)
    assert all(b > a for a, b in zip(xs, xs[1:], strict=False))  # iterations left to right
    assert all(b > a for a, b in zip(ys, ys[1:], strict=False))  # falling loss: y grows down
    assert "allowed range" in text  # E's band
    # How to open the viewer, linked from the top of the section.
    assert "href='#viewer'" in text and "id='viewer'" in text
    assert f"motionphysics view {rd.path}" in text
    assert not re.search(r"(src|href)=['\"]?(https?:)?//", text)
    # A missing initial video is said; a run that was not optimised has no section.
    (rd.path / "video_initial.mp4").unlink()
    assert "video_initial.mp4 missing" in optimisation_section_html(rd.path, params)
    assert optimisation_section_html(rd.path, PARAMS) == ""


def test_svg_curve_log_axis_and_empty():
    from motionphysics.io.report import svg_curve

    assert "log y" in svg_curve([0, 1, 2], [1e-3, 1.0, 10.0], "l")
    assert "log y" not in svg_curve([0, 1, 2], [1.0, 2.0, 3.0], "l")
    assert svg_curve([0, 1], [float("nan"), None], "l") == ""
    assert "<polyline" in svg_curve([0], [5.0], "one point")
