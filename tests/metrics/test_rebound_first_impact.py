"""The rebound ratio measures the bounce a person sees: the rise after the *first* impact
over the fall before it, not the rise after the lowest point of the clip (an object that
bounces and then settles lower had its bounce read as none)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from motionphysics.cli import main
from motionphysics.metrics.physical import first_impact, physical_metrics

ROOT = Path(__file__).resolve().parents[2]

# The demo bird's centroid height [m] per frame (examples/demo.yaml, 2026-12-04): it falls
# 0.28 m, leaps back 9 cm, lands again and rocks onto its side, ending 2.5 cm lower than
# where it first touched the ground.
BIRD = [0.412, 0.404, 0.380, 0.341, 0.286, 0.216, 0.130, 0.141, 0.184, 0.211, 0.222, 0.218,
        0.198, 0.162, 0.120, 0.125, 0.116, 0.102, 0.116, 0.116, 0.115, 0.114, 0.108, 0.106,
        0.104, 0.105, 0.105, 0.106, 0.106, 0.107, 0.106, 0.106, 0.105, 0.105, 0.104, 0.105]  # fmt: skip


def _rigid(heights) -> dict:
    """A rigid 27-particle cube whose centroid follows ``heights`` (z up)."""
    g = np.stack(np.meshgrid(*[np.linspace(-0.05, 0.05, 3)] * 3, indexing="ij"), -1)
    body = g.reshape(-1, 3)
    h = np.asarray(heights, dtype=np.float64)
    x = body[None] + np.stack([np.zeros_like(h), np.zeros_like(h), h], -1)[:, None]
    t = np.arange(h.size) * 0.04
    return {"x": x, "t": t, "gravity": np.array([0.0, 0.0, -9.8])}


def test_first_impact_of_a_bounce_that_settles_lower():
    k, fall, rise = first_impact(BIRD)
    assert k == 6  # the first contact, not frame 17 (the lowest point of the clip)
    assert fall == pytest.approx(0.412 - 0.130)
    assert rise == pytest.approx(0.222 - 0.130)
    m = physical_metrics(_rigid(BIRD), floor=0.0)
    # rise over fall from the first impact: 0.092 / 0.282; the lowest point gave 0.045
    assert m["rebound_ratio"] == pytest.approx(0.092 / 0.282, rel=1e-9)


def test_first_impact_of_plain_series():
    # a fall that comes to rest: no rise
    assert first_impact([1.0, 0.8, 0.5, 0.2, 0.2, 0.2]) == (3, pytest.approx(0.8), 0.0)
    # a fall that never stops within the clip: its last frame, no rise
    assert first_impact([1.0, 0.7, 0.4, 0.1]) == (3, pytest.approx(0.9), 0.0)
    # thrown up first: the fall is from the top of the arc, not from the first frame
    k, fall, rise = first_impact([0.3, 0.5, 0.6, 0.4, 0.1, 0.4, 0.3])
    assert (k, fall, rise) == (4, pytest.approx(0.5), pytest.approx(0.3))
    # a shallow dip on the way down (less than half the deepest drop) is not the impact
    k, _, rise = first_impact([1.0, 0.9, 0.88, 0.89, 0.6, 0.2, 0.5, 0.3])
    assert k == 5 and rise == pytest.approx(0.3)
    # nothing moves
    assert first_impact([0.5, 0.5, 0.5])[1:] == (0.0, 0.0)


def test_the_demo_reads_as_the_bounce_it_shows(tmp_path, capsys):
    """examples/demo.yaml at a third of its particles, through the command line: the bird
    leaves the ground after it lands, and metrics.json and the summary say it bounced."""
    cfg = yaml.safe_load((ROOT / "examples" / "demo.yaml").read_text())
    cfg["scene"]["max_particles"] = 3000
    cfg["sim"].update(grid=32, frames=24)
    cfg["camera"].update(width=64, height=48)
    path = tmp_path / "demo.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out)]) == 0
    summary = capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    heights = np.asarray(metrics["centroid_height"])
    assert heights.argmin() > first_impact(heights)[0]  # it settles lower after the bounce
    assert metrics["rebound_ratio"] > 0.2  # 0.375 on 2026-12-04 (0.04 by the lowest point)
    motion = json.loads((out / "params.json").read_text())["metrics"]["motion"]
    assert motion["asked"] == "bounces_high"
    assert "not as asked" not in motion["lines"][1] and motion["lines"][1] in summary


def test_a_settling_too_small_to_see_is_no_bounce():
    """A steel block dropped 2 cm settles 1.5 mm after it first touches (examples/
    steel_block.yaml): 1 % of its 15 cm height, no bounce to a viewer. With the visible
    rise the first impact is skipped and the rebound is read from the deepest point."""
    steel = [0.106, 0.098, 0.088, 0.0895, 0.088, 0.087, 0.087, 0.087, 0.087, 0.087]
    assert first_impact(steel)[0] == 2  # without a visibility floor: a 1.5 mm "bounce"
    k, fall, rise = first_impact(steel, visible=0.03 * 0.15)
    assert k == 5 and rise == 0.0
    g = np.stack(np.meshgrid(*[np.linspace(-0.075, 0.075, 3)] * 3, indexing="ij"), -1)
    x = g.reshape(-1, 3)[None] + np.stack([np.zeros(10), np.zeros(10), steel], -1)[:, None]
    m = physical_metrics({"x": x, "t": np.arange(10) * 0.04}, floor=0.0)
    assert m["rebound_ratio"] == 0.0


def test_a_body_at_rest_has_no_rebound():
    # a 10 cm body resting on its floor settles 0.02 mm and rises back 0.006 mm: round-off
    # that read as rebound 0.30 (a resting donut, "partly as asked" a bounce). No visible
    # fall (3 % of its height), no rebound.
    rest = [0.05, 0.04999, 0.04998, 0.049986, 0.049984, 0.049985]
    assert physical_metrics(_rigid(rest), floor=0.0)["rebound_ratio"] == 0.0
    # the same shape scaled to a visible fall and rise is a bounce
    drop = [0.05 + 1000 * (h - 0.04998) for h in rest]
    m = physical_metrics(_rigid(drop), floor=0.0)
    assert m["rebound_ratio"] == pytest.approx(0.006 / 0.02, rel=1e-6)
