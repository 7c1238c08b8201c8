"""The three cases of issue 27 scored through ``motionphysics eval`` the way a person
judges them.

Before, eval's motion adherence said: a rubber ball that visibly squashed 26 % at impact
scored deform 0.0077 for "squashes" (adherence 0.456, the same as a ball that squashed
4 %); strawberry jam that covered the floor in 0.56 s scored "fast" 0.67 on "spreads
slowly"; a rod that drooped to the floor scored "oscillate" 0.97 for "gently vibrating".

The runs are made by ``motionphysics simulate CONFIG`` from config files (grid 24, at
most 1,500 particles, 15-20 frames); the counterparts that must score HIGH on the same
words (a slow ooze, a clamped rod that vibrates) are trajectories written in the run
directory format (``trajectory.npz`` and ``run.yaml``), the hand-made labelled
trajectories of :mod:`motionphysics.evaluation.adherence_calibration`.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from motionphysics.cli import main
from motionphysics.evaluation import adherence_calibration as cal

FLOOR = {
    "type": "surface_collider",
    "point": [0, 0, 0],
    "normal": [0, 0, 1],
    "mode": "frictional",
    "friction": 0.3,
}


def _ball(E: float) -> dict:
    """A 20 cm rubber ball dropped 10 cm (E = 6e4 Pa: squashes about a quarter)."""
    return {
        "scene": {
            "source": "builtin:sphere",
            "scale": 0.2,
            "translate": [0, 0, 0.3],
            "max_particles": 1500,
        },
        "prompt": "A rubber ball is dropped and squashes when it hits the floor.",
        "material": {"class": "elastic", "density": 1100, "E": E, "nu": 0.4},
        "sim": {
            "grid": 24,
            "frames": 16,
            "frame_dt": 0.03,
            "substeps": "auto",
            "domain": [[-0.3, -0.3, -0.05], [0.3, 0.3, 0.55]],
        },
        "boundary_conditions": [FLOOR, {"type": "bounding_box"}],
        "camera": {"width": 48, "height": 48},
    }


JAM = {
    # no material block: the kb reads "strawberry jam" (a Newtonian 5 Pa s)
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.2,
        "translate": [0, 0, 0.2],
        "max_particles": 1500,
    },
    "prompt": "Strawberry jam is dropped onto the floor and spreads slowly.",
    "sim": {
        "grid": 24,
        "frames": 15,
        "frame_dt": 0.04,
        "substeps": "auto",
        "domain": [[-0.5, -0.5, -0.05], [0.5, 0.5, 0.45]],
    },
    "boundary_conditions": [FLOOR, {"type": "bounding_box"}],
    "camera": {"width": 48, "height": 48},
}

DROOP = {
    # a soft cord clamped at its left end: it droops onto the floor
    "scene": {
        "source": "builtin:rod",
        "scale": 0.6,
        "translate": [0, 0, 0.3],
        "max_particles": 1500,
    },
    "prompt": "The telephone cord is gently vibrating.",
    "material": {"class": "elastic", "density": 1100, "E": 3.0e5, "nu": 0.4},
    "sim": {
        "grid": 24,
        "frames": 20,
        "frame_dt": 0.04,
        "substeps": "auto",
        "domain": [[-0.4, -0.4, -0.05], [0.4, 0.4, 0.75]],
    },
    "boundary_conditions": [
        FLOOR,
        {"type": "clamp_grid", "box": [[-0.32, -0.1, 0.2], [-0.24, 0.1, 0.4]]},
    ],
    "camera": {"width": 48, "height": 48},
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("three_cases")
    out = {}
    for name, cfg in (
        ("soft", _ball(6.0e4)),
        ("stiff", _ball(3.0e6)),
        ("jam", JAM),
        ("droop", DROOP),
    ):
        (root / f"{name}.yaml").write_text(yaml.safe_dump(cfg))
        rc = main(["--quiet", "simulate", str(root / f"{name}.yaml"), "--out", str(root / name)])
        assert rc == 0, name
        out[name] = root / name
    for name, word, prompt in (
        ("ooze", "oozes", "Honey oozes slowly across the floor."),
        ("vibrate", "vibrates gently", DROOP["prompt"]),
    ):
        d = root / name
        d.mkdir()
        np.savez(d / "trajectory.npz", **cal.WORDS[word][0]())
        (d / "run.yaml").write_text(yaml.safe_dump({"prompt": prompt}))
        out[name] = d
    return out


def _eval(run, capsys, *extra) -> tuple[dict, str]:
    capsys.readouterr()
    assert main(["eval", str(run), *extra]) == 0
    printed = capsys.readouterr().out
    return json.loads((run / "metrics.json").read_text())["motion_adherence"], printed


def test_a_ball_that_squashed_a_quarter_scores_high_for_squashes(runs, capsys):
    prompt = _ball(0)["prompt"]
    soft, printed = _eval(runs["soft"], capsys, "--prompt", prompt)
    stiff, _ = _eval(runs["stiff"], capsys, "--prompt", prompt)
    # the soft ball squashes 29 % at impact (E 6e4 at grid 24); the stiff one 1 %
    assert soft["measurements"]["peak_squash"] > 0.2 > 0.05 > stiff["measurements"]["peak_squash"]
    line = next(e for e in soft["explanations"] if "peak squash" in e)
    pct = int(re.search(r"peak squash (\d+) %", line).group(1))
    assert line.startswith("squashes: ") and 20 <= pct <= 35 and line.endswith(("0.99", "1.00"))
    assert soft["score"] > 0.8  # before: 0.456
    assert stiff["score"] < 0.45  # a ball that hardly squashed does not "squash"
    # the CLI prints the explanation and one line saying what the score measures now
    assert "peak squash" in printed and "harmonic mean" in printed


def test_jam_that_covered_the_floor_scores_low_on_spreads_slowly(runs, capsys):
    jam, _ = _eval(runs["jam"], capsys)
    m = jam["measurements"]
    # the jam spreads over a body length within about half a second of landing
    assert m["spread"] > 1.0 and m["spread_time_s"] < 0.6
    fast = next(r for r in jam["behaviours"] if r["name"] == "fast")
    assert fast["expected"] == "low" and fast["score"] < 0.1 and "pace" in fast["explain"]
    assert jam["score"] < 0.3  # before: "fast" 0.67 and an adherence of 0.85
    # "spreads slowly" on a slow creep (no drop before it: the words without "dropped")
    words = "Strawberry jam spreads slowly across the floor."
    ooze, _ = _eval(runs["ooze"], capsys, "--prompt", words)
    assert ooze["score"] > 0.6
    assert _eval(runs["jam"], capsys, "--prompt", words)[0]["score"] < 0.3


def test_a_rod_that_drooped_scores_low_for_gently_vibrating(runs, capsys):
    droop, _ = _eval(runs["droop"], capsys)
    by = {r["name"]: r for r in droop["behaviours"]}
    # its free end left its shape by more than a gentle vibration would (7 % of L)
    assert by["large_shape"]["score"] < 0.2
    assert droop["score"] < 0.3  # before: "oscillate" 0.97
    vib, _ = _eval(runs["vibrate"], capsys)  # a clamped rod vibrating 3 cm at 4 Hz
    assert vib["score"] > 0.8
    assert vib["measurements"]["osc_swings"] >= 3
