"""The shipped motion prior: it loads, is small, and discriminates the motion groups of
a fixed sample of held-out clips (held-out shapes, held-out phrasings) exactly as its
model card says (deterministic: fixed noise and timesteps)."""

from __future__ import annotations

from pathlib import Path

import pytest

from motionphysics.priors.motion import DEFAULT_WEIGHTS, MotionPrior
from motionphysics.priors.motion_train import discrimination, read_snapshot

SNAPSHOT = Path(__file__).parent / "data" / "motion_heldout_snapshot.npz"


def test_the_shipped_weights_load_and_are_small():
    assert DEFAULT_WEIGHTS.is_file()
    assert DEFAULT_WEIGHTS.stat().st_size <= 10e6
    prior = MotionPrior.from_pretrained(None)
    assert prior.meta["steps"] > 0 and prior.meta["clips"] > 0
    assert prior.latent_shape() == (1, 16, len(prior.mean), 1, 1)


def test_the_shipped_weights_discriminate_held_out_motions_as_recorded():
    prior = MotionPrior.from_pretrained(None)
    res = discrimination(prior, read_snapshot(SNAPSHOT))
    recorded = prior.meta["evaluation"]["snapshot"]
    assert res["clips"] == recorded["clips"] >= 24
    assert res["accuracy"] == pytest.approx(recorded["accuracy"], abs=1e-9)
    assert res["accuracy"] > 3 * res["chance"]
