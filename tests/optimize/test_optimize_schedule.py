"""Frame boosting subsequences and the warm-up + cosine schedule."""

import pytest

from motionphysics.optimize.boosting import effective_boost, frames_for_iteration, subsequences
from motionphysics.optimize.schedule import FINAL_RATIO, learning_rates, lr_factor


def test_subsequences_interleave_and_partition():
    subs = subsequences(num_frames=17, boost=8)  # 16 supervised frames, L = 2
    assert subs[0] == (1, 9) and subs[7] == (8, 16)
    flat = sorted(f for s in subs for f in s)
    assert flat == list(range(1, 17))
    assert [frames_for_iteration(i, 17, 8) for i in (0, 8, 9)] == [(1, 9), (1, 9), (2, 10)]


def test_boost_shrinks_to_supervised_frames():
    assert effective_boost(4, 8) == 3
    assert subsequences(4, 8) == [(1,), (2,), (3,)]
    assert subsequences(6, 1) == [(1, 2, 3, 4, 5)]
    with pytest.raises(ValueError):
        subsequences(1, 8)


def test_schedule_shape():
    total, warm = 20, 3
    f = [lr_factor(i, total, warm) for i in range(total)]
    assert f[:3] == pytest.approx([0.25, 0.5, 0.75])
    assert f[3] == pytest.approx(1.0)
    assert f[-1] == pytest.approx(FINAL_RATIO)
    assert all(a >= b for a, b in zip(f[3:], f[4:], strict=False))
    lrs = learning_rates(["E", "nu"], 0.1, {"nu": 0.01}, 3, total, warm)
    assert lrs == pytest.approx({"E": 0.1, "nu": 0.01})


def test_prior_boost_keeps_clips_long_enough_for_the_prior():
    from motionphysics.optimize.boosting import prior_boost

    # the paper: 150 frames, M = 8 -> 18 frames per subsequence, a 49-frame prior: kept
    assert prior_boost(150, 8, 49) == 8
    # a 16-frame run and the 16-frame motion prior: one subsequence of the 15 frames after
    # the initial state (M = 8 would give it clips of 1-2 frames)
    assert prior_boost(16, 8, 16) == 1
    assert prior_boost(40, 8, 16) == 2  # 2 x 19-20 frames; M = 3 would give 13
    assert prior_boost(40, 8, 8) == 4  # a short prior: 4 x 9-10 frames
    assert prior_boost(200, 8, 16) == 8  # never more than asked
    for frames in range(2, 120):
        for prior in (4, 16, 49):
            m = prior_boost(frames, 8, prior)
            assert 1 <= m <= 8
            assert m == 1 or (frames - 1) // m >= min(prior, 16)
            assert m == 8 or m == frames - 1 or (frames - 1) // (m + 1) < min(prior, 16)
