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
