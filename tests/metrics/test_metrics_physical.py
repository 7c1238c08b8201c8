"""Physical diagnostics that say what they measure: resolved frequencies only, extent vs
centroid height above the floor, total energy including the stored elastic energy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from motionphysics.metrics.physical import energy_density, oscillation, physical_metrics


def test_frequency_at_nyquist_is_not_reported():
    dt = 0.04  # 25 fps: Nyquist 12.5 Hz
    y = np.cos(np.pi * np.arange(30))  # +1, -1, +1 ...: exactly the Nyquist frequency
    out = oscillation(y, dt)
    assert out["frequency_hz"] is None and "aliasing" in out["frequency_reason"]
    assert out["frequency_peak_hz"] == pytest.approx(12.5, abs=0.5)
    short = oscillation(np.sin(2 * np.pi * 1.0 * np.arange(30) * dt), dt)  # 1.2 s of 1 Hz
    assert short["frequency_hz"] is None and "periods" in short["frequency_reason"]
    ok = oscillation(np.sin(2 * np.pi * 2.0 * np.arange(50) * dt), dt)  # 4 periods of 2 Hz
    assert ok["frequency_hz"] == pytest.approx(2.0, abs=0.3) and ok["frequency_reason"] is None


def test_energy_densities_match_their_closed_forms():
    E, nu = 1.0e5, 0.3
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    F = np.diag([1.1, 1.0, 1.0])[None]
    # fixed corotated, pure stretch: R = I, ||F - R||^2 = 0.01, J - 1 = 0.1
    assert energy_density(F, "elastic", {"E": E, "nu": nu})[0] == pytest.approx(
        mu * 0.01 + 0.5 * lam * 0.01
    )
    # the same with a rotation in front: invariant
    c, s = math.cos(0.7), math.sin(0.7)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    assert energy_density(Rz @ F, "elastic", {"E": E, "nu": nu})[0] == pytest.approx(
        mu * 0.01 + 0.5 * lam * 0.01
    )
    e = math.log(1.1)
    assert energy_density(F, "metal", {"E": E, "nu": nu})[0] == pytest.approx(
        mu * e * e + 0.5 * lam * e * e
    )
    J = 0.9
    k = 2.0e6
    Fj = (np.eye(3) * J ** (1 / 3))[None]
    assert energy_density(Fj, "newtonian", {"kappa": k})[0] == pytest.approx(
        0.25 * k * (J * J - 1 - 2 * math.log(J))
    )
    # the fluid potential is the one whose Kirchhoff pressure the solver uses: J psi'(J) = kappa/2 (J^2 - 1)
    h = 1e-6
    dpsi = (
        energy_density((np.eye(3) * (J + h) ** (1 / 3))[None], "newtonian", {"kappa": k})[0]
        - energy_density((np.eye(3) * (J - h) ** (1 / 3))[None], "newtonian", {"kappa": k})[0]
    ) / (2 * h)
    assert J * dpsi == pytest.approx(0.5 * k * (J * J - 1), rel=1e-6)
    assert energy_density(np.eye(3)[None], "non_newtonian", {"mu": 10.0, "kappa": 100.0})[0] == 0.0


def test_total_energy_includes_elastic_energy_and_names_its_terms():
    P, T = 8, 3
    x = np.zeros((T, P, 3)) + np.arange(P)[None, :, None] * 0.01
    F = np.repeat(np.repeat(np.eye(3)[None, None], T, 0), P, 1).copy()
    F[1] = np.diag([1.1, 1.0, 1.0])
    traj = {
        "x": x,
        "t": np.arange(T) * 0.04,
        "F": F,
        "volume": np.full(P, 1e-3),
        "mass": np.full(P, 1.0),
    }
    mat = {"class": "elastic", "sim": {"E": 1e5, "nu": 0.3}}
    out = physical_metrics(traj, mat)
    psi = energy_density(F[1, :1], "elastic", mat["sim"])[0]
    assert (
        out["elastic_energy"][1] == pytest.approx(P * 1e-3 * psi) and out["elastic_energy"][0] == 0
    )
    assert out["total_energy_terms"] == ["kinetic", "potential", "elastic"]
    bare = physical_metrics(traj)
    assert bare["elastic_energy"] is None and bare["total_energy_terms"] == ["kinetic", "potential"]
    assert "no material" in bare["elastic_energy_reason"]


def test_rod_spinning_flat_extent_vs_centroid_height():
    # a rod lying on the floor (z = 0.03) turning about the vertical axis: its vertical
    # extent does not change and neither does its centroid height above the floor
    s = np.linspace(-0.3, 0.3, 61)
    T = 20
    xs = []
    for i in range(T):
        a = 0.2 * i
        xs.append(np.stack([s * math.cos(a), s * math.sin(a), np.full_like(s, 0.03)], -1))
    x = np.stack(xs)
    x[:, ::2, 2] += 0.02  # some thickness
    out = physical_metrics({"x": x, "t": np.arange(T) * 0.04}, floor=0.0)
    assert out["final_extent_ratio"] == pytest.approx(1.0)
    assert out["final_centroid_height_above_floor"] == pytest.approx(
        0.03 + 0.02 * 31 / 61, rel=1e-6
    )
    assert out["final_centroid_height_ratio"] == pytest.approx(1.0)
    assert out["floor_source"].startswith("given")
