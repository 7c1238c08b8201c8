"""The extent damping ratio (issue 27, item 5): measured on a free decay, never negative.

The demo's report showed -0.19: the mean log decrement of every positive peak of the
detrended extent, where a landing and a change of resting pose make later peaks larger
than earlier ones. Now the decay is read from the largest swing on, and a swing that does
not decay steadily is "not measurable" with the reason, which the report shows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from motionphysics.io.report import physical_rows
from motionphysics.metrics.physical import oscillation


def test_free_decay_gives_its_damping_ratio():
    dt, f, zeta = 0.01, 3.0, 0.05
    t = np.arange(300) * dt
    y = np.exp(-zeta * 2 * math.pi * f * t) * np.cos(2 * math.pi * f * t)
    out = oscillation(y, dt)
    # the log decrement of a sampled cosine: within 0.01 of zeta at 33 samples per period
    assert out["damping_ratio"] == pytest.approx(zeta, abs=0.01)
    assert out["damping_reason"] is None


def test_growing_peaks_are_not_measurable_and_say_why():
    dt = 0.04
    t = np.arange(40) * dt
    y = (1.0 + 0.8 * t) * np.sin(2 * math.pi * 2.0 * t)  # a driven, growing swing
    out = oscillation(y, dt)
    assert out["frequency_hz"] == pytest.approx(2.0, abs=0.3)
    assert out["damping_ratio"] is None
    assert out["damping_reason"].startswith("not measurable")
    rows = {label: value for label, value, _ in physical_rows({"height_oscillation": out})}
    assert rows["extent damping ratio"] == out["damping_reason"]  # the report says why
