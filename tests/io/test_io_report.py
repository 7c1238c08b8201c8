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
