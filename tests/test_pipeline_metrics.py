"""Physical diagnostics on analytic trajectories (free fall, flattening, damped oscillation)."""

from __future__ import annotations

import math

import numpy as np

from motionphysics.metrics.physical import oscillation, physical_metrics


def _cube(n=6):
    g = np.linspace(-0.1, 0.1, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def test_free_fall_energy_is_conserved():
    p0 = _cube() + [0, 0, 1.0]
    t = np.arange(20) * 0.02
    x = p0[None] + np.array([0, 0, -0.5 * 9.8])[None, None] * (t**2)[:, None, None]
    m = np.full(len(p0), 0.01)
    out = physical_metrics({"x": x, "t": t, "mass": m, "gravity": np.array([0, 0, -9.8])})
    ke, pe = np.array(out["kinetic_energy"]), np.array(out["potential_energy"])
    # central differences are exact for a parabola inside; ends are one-sided
    np.testing.assert_allclose((ke + pe)[1:-1], 0.0, atol=1e-9)
    assert math.isclose(ke[10], 0.5 * m.sum() * (9.8 * t[10]) ** 2, rel_tol=1e-9)
    assert math.isclose(out["final_height_ratio"], 1.0, rel_tol=1e-9)
    assert math.isclose(out["spread_ratio"], 1.0, rel_tol=1e-9)
    assert out["centroid_drop"] > 0.5 * 9.8 * t[-1] ** 2 * 0.99


def test_flattening_blob_lowers_height_and_raises_spread():
    p0 = _cube()
    T = 10
    s = np.linspace(0, 1, T)
    scale = np.stack([1 + 2 * s, 1 + 2 * s, 1 - 0.8 * s], -1)  # [T, 3]
    x = p0[None] * scale[:, None, :]
    F = np.zeros((T, len(p0), 3, 3))
    for i in range(T):
        F[i] = np.diag(scale[i])
    out = physical_metrics({"x": x, "t": np.arange(T) * 0.04, "det_F": np.linalg.det(F)})
    assert math.isclose(out["final_height_ratio"], 0.2, rel_tol=1e-6)
    assert math.isclose(out["spread_ratio"], 3.0, rel_tol=1e-6)
    assert math.isclose(out["volume_ratio"]["final_mean"], 9 * 0.2, rel_tol=1e-6)
    assert "per kg" in out["mass_unit"]


def test_oscillation_frequency_and_damping():
    dt, f, zeta = 0.01, 3.0, 0.05
    t = np.arange(300) * dt
    wd = 2 * math.pi * f
    y = np.exp(-zeta * 2 * math.pi * f * t) * np.cos(wd * t)
    out = oscillation(y, dt)
    assert abs(out["frequency_hz"] - f) < 0.2
    assert abs(out["damping_ratio"] - zeta) < 0.02
    still = oscillation(np.ones(50), dt)
    assert still["frequency_hz"] is None and still["damping_ratio"] is None


def test_rebound_ratio():
    p0 = _cube()
    t = np.arange(30) * 0.02
    # falls 0.4 m, then rises 0.2 m: a bounce to half the drop height
    z = np.concatenate([np.linspace(0.5, 0.1, 15), np.linspace(0.1, 0.3, 15)])
    x = p0[None] + np.stack([np.zeros(30), np.zeros(30), z], -1)[:, None, :]
    out = physical_metrics({"x": x, "t": t})
    assert abs(out["rebound_ratio"] - 0.5) < 1e-6
    still = physical_metrics({"x": np.repeat(p0[None], 5, 0), "t": np.arange(5) * 0.04})
    assert still["rebound_ratio"] == 0.0 and still["max_kinetic_energy"] < 1e-20
