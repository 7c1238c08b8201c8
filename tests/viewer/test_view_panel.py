"""The viewer's side panel: material with provenance, metrics, optimisation curves."""

from __future__ import annotations

import io
import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from chromium_cdp import free_port  # noqa: E402


def test_panel_texts():
    from motionphysics.viewer.server import history_series, material_markdown, metrics_markdown

    params = {
        "class": "elastic",
        "density": 1100.0,
        "params": {"E": 2.0e6, "nu": 0.42},
        "sim": {"E": 1.5e5, "nu": 0.42, "density": 1100.0},
        "provenance": {"backend": "kb", "sources": {"E": "kb", "nu": "config"}},
    }
    md = material_markdown(params)
    assert "elastic" in md and "estimated by kb" in md
    assert "| E | 2.000e+06 | 1.500e+05 | kb |" in md and "| nu | 0.42 | 0.42 | config |" in md
    multi = material_markdown(
        {"objects": [{"name": "axe", **params}, {"name": "toy", "class": "foam", "params": {}}]}
    )
    assert "**axe**" in multi and "**toy**: foam" in multi
    mt = metrics_markdown({"schema": "x", "max_speed": 1.5, "volume_ratio": {"overall_min": 0.9}})
    assert "| max\\_speed | 1.5 |" in mt and "volume\\_ratio.overall\\_min" in mt
    assert "schema" not in mt
    hist = [
        {"iteration": 0, "loss": 2.0, "params": {"E": 1e5}},
        {"iteration": 1, "loss": 1.0, "params": {"E": 2e5, "nu": 0.3}},
    ]
    s = history_series(hist)
    np.testing.assert_array_equal(s["iteration"], [0, 1])
    np.testing.assert_array_equal(s["loss"], [2.0, 1.0])
    np.testing.assert_array_equal(s["param:E"], [1e5, 2e5])
    assert math.isnan(s["param:nu"][0]) and s["param:nu"][1] == 0.3


def test_optimised_run_panel_has_curves(tiny_run, tmp_path):
    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import Viewer

    run_dir = tmp_path / "opt"
    shutil.copytree(tiny_run, run_dir)
    with open(run_dir / "log.jsonl", "w") as fh:
        for i in range(5):
            rec = {"iteration": i, "loss": 1.0 / (i + 1), "params": {"E": 1e5 + i, "nu": 0.4}}
            fh.write(json.dumps(rec) + "\n")
        fh.write('{"iteration": 5, "loss"')  # a torn last line of a killed run
    run = load_run(run_dir)
    assert len(run.history()) == 5
    viewer = Viewer([run], port=free_port(), out=io.StringIO())
    viewer.start()
    try:
        plots = viewer.views[0].plots
        assert sorted(plots) == ["loss", "param:E", "param:nu"]
        np.testing.assert_allclose(plots["loss"].data[1], [1.0, 0.5, 1 / 3, 0.25, 0.2])
        titles = sorted(p.title for p in plots.values())
        assert titles == ["E (SI)", "loss", "nu (SI)"], titles
    finally:
        viewer.stop()
