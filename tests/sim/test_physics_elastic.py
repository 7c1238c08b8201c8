"""Physics validation of the elastic (fixed corotated) material against analytic theory.

1. Axial vibration of a free-free bar: the fundamental frequency f1 = c / (2 L) with the
   bar wave speed c = sqrt(E / rho) (thin-bar theory, e.g. Graff 1975, "Wave Motion in
   Elastic Solids", sec. 2.1; exact for the continuum when nu = 0, since then there is no
   lateral (Poisson) motion and so no Rayleigh-Love correction).
2. An elastic ball dropped on the ground rebounds and recovers its rest shape (an elastic
   material has no plastic memory: once contact ends, its shape can only oscillate about
   the rest shape); a plastic ball of the same stiffness, the control, does not.

Materials are given directly in simulation units (no physical->sim map involved).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from physics_helpers import box_lattice, box_volumes, run, sphere_lattice, zero_crossing_period
from reference_data import bar_axial_frequency


def _bar_frequency(cells_per_length: int, ppc: int, periods: float) -> tuple[float, float]:
    """Simulated and analytic fundamental frequency [Hz] of a free-free bar along x."""
    E, rho, nu = 1.0e5, 1000.0, 0.0
    length, side = 0.5, 0.125
    dx = length / cells_per_length
    h = dx / ppc
    lo = np.array([0.25, 0.5 - side / 2, 0.5 - side / 2])
    hi = lo + np.array([length, side, side])
    x0 = box_lattice(lo, hi, h)
    vol = box_volumes(lo, hi, len(x0))
    f_ref = bar_axial_frequency(E, rho, length)
    # Initial velocity in the shape of mode 1, u(xi) = cos(pi xi / L): it excites that mode
    # alone. 0.05 m/s against c = 10 m/s keeps the strain below 0.5 % (linear regime).
    xi = x0[:, 0] - lo[0]
    v0 = np.zeros_like(x0)
    v0[:, 0] = 0.05 * np.cos(np.pi * xi / length)
    c = math.sqrt(E / rho)
    dt = 0.15 * dx / c  # CFL 0.15, well inside the solver's 0.4
    period = 1.0 / f_ref
    frame_substeps = max(1, int(round(period / 40 / dt)))  # ~40 samples per period
    frames = int(math.ceil(periods * period / (frame_substeps * dt)))
    n = int(round(1.0 / dx)) + 1
    r = run(
        x0,
        vol,
        {"class": "elastic", "E": E, "nu": nu, "density": rho},
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(n, n, n),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        gravity=(0.0, 0.0, 0.0),
        velocity=v0,
    )
    left = xi < length / 8
    right = xi > 7 * length / 8
    elong = r.x[:, right, 0].mean(axis=1) - r.x[:, left, 0].mean(axis=1)
    elong = elong - elong[0]  # the bar's rest length is its initial length (no gravity)
    f_sim = 1.0 / zero_crossing_period(r.t, elong)
    return f_sim, f_ref


def test_bar_axial_frequency_coarse():
    # 16 cells along the bar, 2 particles per cell per axis (2048 particles).
    f_sim, f_ref = _bar_frequency(cells_per_length=16, ppc=2, periods=3.0)
    assert abs(f_sim - f_ref) / f_ref < 0.10, (f_sim, f_ref)


@pytest.mark.slow
def test_bar_axial_frequency_fine():
    f_sim, f_ref = _bar_frequency(cells_per_length=32, ppc=2, periods=4.0)
    assert abs(f_sim - f_ref) / f_ref < 0.10, (f_sim, f_ref)


def _drop_ball(material: dict, cells: int = 32, ppc: int = 2, duration: float = 0.32):
    """Drop a ball (radius 0.1 m, centre 0.3 m) on the slip floor of a unit box.

    Returns the rollout, the floor height [m] and the impact speed [m/s] of free fall.
    """
    dx = 1.0 / cells
    h = dx / ppc
    radius = 0.1
    x0 = sphere_lattice((0.5, 0.5, 0.3), radius, h)
    vol = np.full(len(x0), h**3)
    from motionphysics.sim.solver import stable_dt

    dt = 0.75 * stable_dt(material, dx)  # CFL 0.3
    frame_substeps = max(1, int(round(2.5e-3 / dt)))
    frames = int(math.ceil(duration / (frame_substeps * dt)))
    n = cells + 1
    r = run(
        x0,
        vol,
        material,
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(n, n, n),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        boundary_conditions=[{"type": "bounding_box", "friction": 0.0, "padding": 3}],
    )
    floor = 3 * dx
    bottom0 = x0[:, 2].min() - h / 2
    v_impact = math.sqrt(2 * 9.8 * (bottom0 - floor))
    return r, floor, v_impact


def _gyration_radii(x: np.ndarray) -> np.ndarray:
    """Principal radii of gyration [m] (ascending) of a particle cloud (P, 3)."""
    d = x - x.mean(axis=0)
    return np.sqrt(np.linalg.eigvalsh(d.T @ d / len(d)))


def _bounce_metrics(r, v_impact: float) -> dict:
    vz = r.v[:, :, 2].mean(axis=1)  # centre-of-mass velocity (equal masses)
    i_impact = int(np.argmin(vz))  # fastest downward: the moment contact begins to act
    after = np.arange(len(vz)) > i_impact
    i_up = int(np.argmax(np.where(after, vz, -np.inf)))  # largest upward speed after it
    # Flight after the bounce: moving up and the bottom of the ball above the floor layer.
    radii0 = _gyration_radii(r.x[0])
    flight = [k for k in range(i_up, len(vz)) if vz[k] > 0.05 * v_impact]
    shape = np.array([_gyration_radii(r.x[k]) / radii0 for k in flight]) if flight else None
    return {
        "v_in": -vz[i_impact],
        "v_out": vz[i_up],
        "restitution": vz[i_up] / v_impact,
        "flight_frames": len(flight),
        "shape_ratio_mean": None if shape is None else shape.mean(axis=0),
        "aspect_mean": None if shape is None else float(np.mean(shape[:, 0] / shape[:, 2])),
    }


_BALL = {"E": 5.0e5, "nu": 0.3, "density": 1000.0}


def test_elastic_ball_rebounds_and_recovers_shape():
    r, _, v_impact = _drop_ball({"class": "elastic", **_BALL})
    m = _bounce_metrics(r, v_impact)
    # Free fall until contact: the fastest downward speed is that of free fall from the
    # drop height (within 5 %: the grid wall acts a fraction of a cell early).
    assert abs(m["v_in"] / v_impact - 1.0) < 0.05, m
    # A perfectly elastic sphere on a rigid frictionless wall rebounds with e close to 1
    # (Hunter 1957, J. Mech. Phys. Solids 5, 162: wave radiation takes < 1 % of the energy).
    # The MPM wall removes the normal momentum of the nodes in its layer at contact, an
    # inelastic loss, so we only require that most of the speed comes back.
    assert m["restitution"] > 0.5, m
    assert m["flight_frames"] >= 10, m
    # Back in flight, the principal radii of gyration return to the sphere's: the elastic
    # law has no memory; what remains is vibration about the rest shape.
    assert np.all(np.abs(m["shape_ratio_mean"] - 1.0) < 0.03), m
    assert m["aspect_mean"] > 0.97, m


def test_plastic_ball_control_stays_flattened():
    # The control that makes the shape check above meaningful: a ball of the same stiffness
    # whose yield stress (2 kPa) is far below the impact stress rho c v ~ 40 kPa lands flat,
    # does not bounce, and keeps the flattened shape.
    r, _, v_impact = _drop_ball({"class": "metal", "tau_Y": 2.0e3, **_BALL})
    m = _bounce_metrics(r, v_impact)
    assert m["restitution"] < 0.3, m
    radii = _gyration_radii(r.x[-1]) / _gyration_radii(r.x[0])
    assert radii[0] / radii[2] < 0.8, radii
