"""Training clips of the motion prior: deterministic per seed, balanced draws, and the
setups the issue asks for (centimetres to a metre, gravity off, impulses, slender)."""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.language.captions import GROUPS
from motionphysics.materials.catalog import MATERIALS
from motionphysics.priors.motion_data import (
    KEEP_PARTICLES,
    MAX_ATTEMPTS,
    MAX_ATTEMPTS_OF,
    TARGETS,
    TRAIN_SHAPES,
    clip_measures,
    draw_motion_spec,
    make_clip,
)

G0 = 9.8
RANGE = {(c, p.name): (float(p.low), float(p.high)) for c in MATERIALS for p in MATERIALS[c].params}


def test_draws_are_deterministic_and_cover_the_setups():
    specs = [draw_motion_spec(0, i, a) for i in range(360) for a in range(2)]
    again = [draw_motion_spec(0, i, a) for i in range(360) for a in range(2)]
    assert [s.to_dict() for s in specs] == [s.to_dict() for s in again]
    assert draw_motion_spec(1, 5).to_dict() != draw_motion_spec(0, 5).to_dict()
    sizes = np.array([s.scale for s in specs])
    assert sizes.min() >= 0.01 and sizes.max() <= 1.0
    assert (sizes < 0.03).any() and (sizes > 0.5).any()
    off = [s for s in specs if s.gravity == 0.0]
    assert off and all(s.velocity[2] < 0 for s in off)  # thrown at the floor
    assert any(s.impulse is not None for s in specs)
    assert {s.shape for s in specs} == set(TRAIN_SHAPES)
    # every target (8 groups and "no group") gets the same share of clip indices
    targets = [draw_motion_spec(0, i).target for i in range(90)]
    assert {t: targets.count(t) for t in TARGETS} == dict.fromkeys(TARGETS, 10)
    assert set(TARGETS) == {*GROUPS, None}
    # proposals: crumbles draws sand, oozes draws the fluids
    assert {draw_motion_spec(0, 6 + 9 * k).cls for k in range(10)} == {"sand"}
    assert {draw_motion_spec(0, 4 + 9 * k).cls for k in range(20)} <= {"newtonian", "non_newtonian"}


def test_speed_measures_are_froude_scaled():
    t = np.arange(16) * 0.05
    x = np.zeros((16, 8, 3))
    x[:, :, 0] = np.linspace(0, 1, 8)  # a 1 m object
    v = np.zeros((16, 8, 3))
    v[..., 2] = 0.3
    big = clip_measures(x, v, t)
    small = clip_measures(x * 0.01, v * 0.1, t)  # 1 cm at sqrt(0.01) the speed
    assert big["late_speed"] == pytest.approx(small["late_speed"], rel=1e-6)


@pytest.mark.slow
def test_a_clip_is_deterministic_per_seed():
    """Clip 8 (target: no group, so one simulation) twice."""
    a, b = make_clip(3, 8), make_clip(3, 8)
    assert a["attempts"] == 1 and a["spec"]["target"] is None
    for k in ("x", "F", "v", "t", "gravity"):
        assert np.array_equal(a[k], b[k]), k
    assert a["spec"] == b["spec"] and a["group"] == b["group"] and a["measures"] == b["measures"]
    assert a["x"].shape == (16, min(KEEP_PARTICLES, a["x"].shape[1]), 3)
    assert np.isfinite(a["F"]).all()


def test_generation_keeps_shards_already_written_and_refuses_another_seed(tmp_path):
    """``prior data`` resumes: a shard already on disk is kept as it is (nothing is
    simulated for it), and the same OUT with another seed is refused (it would mix data
    sets)."""
    import json

    from motionphysics.errors import UserInputError
    from motionphysics.priors.motion_data import SHARD_SIZE, generate

    out = tmp_path / "d"
    out.mkdir()
    shard = out / "shard-00000.npz"
    np.savez(shard, marker=np.arange(3))
    before = shard.stat().st_mtime_ns
    done = []
    meta = generate(out, SHARD_SIZE, seed=11, on_shard=lambda *a: done.append(a))
    assert shard.stat().st_mtime_ns == before and list(np.load(shard)) == ["marker"]
    assert done == [(1, 1, 0)] and meta["seed"] == 11 and meta["clips"] == SHARD_SIZE
    assert json.loads((out / "dataset.json").read_text())["schema"] == "motionphysics.motion-data/1"
    with pytest.raises(UserInputError, match="seed is 11 there but 12 was asked"):
        generate(out, SHARD_SIZE, seed=12)
    assert json.loads((out / "dataset.json").read_text())["seed"] == 11


def test_wobble_and_ooze_draws_scale_with_the_object():
    """A wobble needs a static sag of a few per cent (E / (rho g L) in 3..20) and an ooze a
    slump time of about the clip (mu / (rho g L) in 1..40 s) whatever the object's size:
    the proposals draw the ratio, switch gravity on and set the object down."""
    wob = [draw_motion_spec(0, 2 + 9 * k, a) for k in range(30) for a in range(2)]
    assert {s.target for s in wob} == {"wobbles"}
    for s in wob:
        assert s.gravity == G0 and -0.2 - 1e-9 <= s.velocity[2] / (G0 * s.scale) ** 0.5 <= 0.0
        if "E" in s.params and s.params["E"] > RANGE[s.cls, "E"][0]:  # else at the class's floor
            assert 3.0 <= s.params["E"] / (s.density * G0 * s.scale) <= 20.0
        if s.cls == "elastic":
            assert 0.45 <= s.params["nu"] <= 0.49
    sizes = [s.scale for s in wob]
    assert max(sizes) / min(sizes) > 3  # a range of sizes, each with its own E
    ooze = [draw_motion_spec(0, 4 + 9 * k, a) for k in range(30) for a in range(2)]
    for s in ooze:
        assert s.gravity == G0 and 0.08 <= s.scale <= 0.6
        lo, hi = RANGE[s.cls, "mu"]
        if lo < s.params["mu"] < hi:
            assert 1.0 <= s.params["mu"] / (s.density * G0 * s.scale) <= 40.0
        if s.cls == "non_newtonian":
            assert s.params["tau_Y"] <= 50.0
    assert MAX_ATTEMPTS_OF["wobbles"] > MAX_ATTEMPTS and MAX_ATTEMPTS_OF["oozes"] > MAX_ATTEMPTS
