"""The motion asked for and simulated (summary and report of a refinement), on hand-made
trajectories whose motion groups are known from the caption rules."""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.priors.motion_summary import (
    asked_motion,
    motion_lines,
    motion_record,
    trajectory_motion,
)


def _ball(n=400, r=0.05, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * r * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    return p


def _drop(rebound: float, T=24, h0=0.3, r=0.05):
    """A rigid ball (radius r) dropped from centroid height h0 onto z = 0 that rises back
    to ``rebound`` of its fall; the impact falls on frame 10, the clip ends before the
    second impact."""
    g = 9.8
    t_hit = np.sqrt(2 * (h0 - r) / g)
    t = np.arange(T) * t_hit / 10
    v_up = rebound**0.5 * g * t_hit
    after = t - t_hit
    z = np.where(t < t_hit, h0 - 0.5 * g * t**2, r + v_up * after - 0.5 * g * after**2)
    vz = np.where(t < t_hit, -g * t, v_up - g * after)
    if rebound == 0.0:  # lands dead and rests
        z, vz = np.maximum(z, r), np.where(t < t_hit, vz, 0.0)
    assert (z >= r - 1e-12).all()
    base = _ball(r=r)
    x = base[None] + np.stack([np.zeros(T), np.zeros(T), z], 1)[:, None]
    vel = np.zeros_like(x)
    vel[..., 2] = vz[:, None]
    return x, vel, t


def test_a_high_bounce_and_a_dead_landing_read_as_their_groups():
    hi = trajectory_motion(*_drop(0.6), "elastic")
    assert hi["group"] == "bounces_high"
    assert hi["measures"]["rebound"] == pytest.approx(0.6, rel=0.05)  # frames miss the apex
    dead = trajectory_motion(*_drop(0.0), "metal")
    assert dead["group"] == "keeps_shape"
    assert dead["measures"]["rebound"] < 0.04


def test_the_record_puts_the_asked_motion_beside_before_and_after():
    x0, v0, t = _drop(0.0)
    x1, v1, _ = _drop(0.6)
    rec = motion_record(
        "A rubber ball is dropped and bounces high", "elastic", t, (x0, v0), (x1, v1)
    )
    assert rec["asked"] == "bounces_high"
    assert rec["before"]["group"] == "keeps_shape" and rec["after"]["group"] == "bounces_high"
    lines = motion_lines(rec)
    assert lines[0].startswith("motion asked: bounces high")
    assert "before refinement: keeps shape" in lines[1]
    assert lines[2].endswith("(as asked)")
    # eval's motion adherence of each: the dead landing fails "bounces high", the bounce
    # passes, and the summary says the score rose
    a0, a1 = rec["before"]["adherence"]["score"], rec["after"]["adherence"]["score"]
    assert a0 < 0.5 < a1
    assert lines[3] == f"  motion adherence (eval, 0..1): {a0:.2f} before, {a1:.2f} after (rose)"
    none = motion_record("A rubber ball", "elastic", t, (x0, v0), (x1, v1))
    assert none["asked"] is None
    assert "names none" in motion_lines(none)[0]


@pytest.mark.parametrize(
    ("group", "score", "verdict", "advice"),
    [
        ("bounces_high", 0.30, "as asked", False),
        ("barely_bounces", 0.74, "close to what was asked", False),
        (None, 0.54, "partly as asked: between motion groups", False),
        ("keeps_shape", 0.05, "not as asked", True),
        ("keeps_shape", None, "not as asked", True),
    ],
)
def test_a_plain_runs_verdict(group, score, verdict, advice):
    """The verdict of a run without refinement: the caption group first, eval's adherence
    next; "not as asked" only when another named group was simulated and the adherence is
    under NEAR_ADHERENCE, and only then the line that says what moves it."""
    from motionphysics.priors.motion_summary import plain_motion_lines

    measures = {"rebound": 0.33, "max_deform": 0.006, "deform": 0.001, "max_spread": 1.03}
    rec = {
        "asked": "bounces_high",
        "simulated": {
            "group": group,
            "measures": {**measures, "wobble": 0.0},
            "adherence": {"score": score},
        },
    }
    lines = plain_motion_lines(rec)
    assert lines[0] == "motion asked: bounces high (the prompt's motion words)"
    assert lines[1].endswith(f"({verdict})")
    assert ("--prior motion" in lines[-1]) == advice
    assert any("adherence" in x for x in lines) == (score is not None)


def test_the_refined_record_reads_the_motion_asked_for_what_the_material_can_show():
    """A refined run reads the prompt as a run without refinement does (``asked_motion``):
    "crumbles" is sand's word, so water that "collapses and splashes" asks for a splash."""
    x0, v0, t = _drop(0.0)
    prompt = "A block of water collapses and splashes across the floor of a tank."
    rec = motion_record(prompt, "newtonian", t, (x0, v0), (x0, v0))
    assert rec["asked"] == asked_motion(prompt, "newtonian")[0] == "splashes"
    assert motion_record(prompt, "sand", t, (x0, v0), (x0, v0))["asked"] == "crumbles"
