"""Physics validation of sand (Drucker-Prager) in granular column collapses.

A planar column of sand of length L0 and height H0 = a L0 (aspect ratio a) against a back
wall is released and spreads along the floor (a thin slab between slip walls, i.e. the
two-dimensional channel experiment). References:

- the final slope of the deposit is at the material's angle of repose, which for a
  cohesionless Drucker-Prager (Mohr-Coulomb) material is its friction angle (Klar et
  al. 2016, ACM Trans. Graph. 35(4) 103; Nedderman 1992, "Statics and Kinematics of
  Granular Materials", ch. 2); we require it within 5 degrees.
- the run-out (L_inf - L0) / L0 grows with a as 1.2 a for a < 2.3 and 1.9 a^(2/3) beyond
  (Lube, Huppert, Sparks & Freundt 2005, Phys. Rev. E 72, 041301; for axisymmetric
  columns Lube et al. 2004, J. Fluid Mech. 508, 175-199 found 1.24 a and 1.6 a^(1/2)),
  independent of the grain material; we test the trend (coarse) and each run-out
  against the fit within 20 % (fine).

Materials in simulation units: E = 1e5 Pa (elastic strain rho g H / E below 2 %),
nu = 0.3, rho = 1600 kg/m^3 (dry sand), friction angle 30 degrees; the floor is a Coulomb
frictional plane with mu = tan(30 degrees) (basal friction equal to the internal one).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from physics_helpers import box_lattice, box_volumes, run
from reference_data import lube_planar_runout

PHI = 30.0


def _collapse(
    a: float, H0: float, dx: float, duration: float, ppc: int = 2, phi: float = PHI
) -> dict:
    E, nu, rho = 1.0e5, 0.3, 1600.0
    L0 = H0 / a
    pad = 3
    # Grid walls act on the nodes i < pad (and i >= n - pad): material is stopped about
    # half a cell beyond the first free node, so the walls' effective planes are at
    # (pad - 1/2) dx from the domain edges (measured: sand at rest against them reaches
    # 2.7 dx). Filling the slab up to those planes keeps it from widening into the gap.
    wall = (pad - 0.5) * dx
    floor = (pad - 0.5) * dx
    run_out_max = L0 * (1.0 + 1.5 * lube_planar_runout(a)) + 4 * dx  # room to spare
    nx = int(math.ceil((wall + run_out_max) / dx)) + pad + 3
    ny = 2 + 2 * pad + 1  # 2 free cells; the slab is 3 cells thick between the wall planes
    nz = int(math.ceil((floor + H0) / dx)) + pad + 4
    lo = np.array([wall, (pad - 0.5) * dx, floor])
    hi = lo + np.array([L0, 3 * dx, H0])
    h = dx / ppc
    x0 = box_lattice(lo, hi, h)
    vol = box_volumes(lo, hi, len(x0))
    c = math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho))
    dt = 0.3 * dx / c
    frame_substeps = max(1, int(round(0.01 / dt)))
    frames = int(math.ceil(duration / (frame_substeps * dt)))
    r = run(
        x0,
        vol,
        {"class": "sand", "E": E, "nu": nu, "theta_fric": phi, "density": rho},
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(nx, ny, nz),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        boundary_conditions=[
            # Floor plane through the last wall node layer: nodes at or below it are in
            # contact; listed first so it sees the incoming normal velocity.
            {
                "type": "surface_collider",
                "point": [0, 0, (pad - 1) * dx],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": math.tan(math.radians(phi)),
            },
            {"type": "bounding_box", "friction": 0.0, "padding": pad},
        ],
    )
    xf = r.x[-1]
    run_out = xf[:, 0].max() + h / 2 - wall
    # Surface profile: top of the deposit in columns one cell wide.
    edges = np.arange(wall, wall + run_out + dx, dx)
    idx = np.digitize(xf[:, 0], edges) - 1
    xs, zs = [], []
    for i in range(len(edges) - 1):
        sel = idx == i
        if np.any(sel):
            xs.append(0.5 * (edges[i] + edges[i + 1]))
            zs.append(xf[sel, 2].max() + h / 2 - floor)
    xs, zs = np.array(xs), np.array(zs)
    top = zs.max()
    band = (zs > 0.2 * top) & (zs < 0.8 * top)
    slope = np.polyfit(xs[band], zs[band], 1)[0] if band.sum() >= 3 else float("nan")
    speed = np.abs(r.v[-1]).max()
    return {
        "a": a,
        "phi": phi,
        "runout": float((run_out - L0) / L0),
        "runout_lube": lube_planar_runout(a),
        "angle": float(math.degrees(math.atan(-slope))),
        "slope_points": int(band.sum()),
        "final_speed": float(speed),
        "height": float(top / H0),
    }


# Coarse: both columns 8 cells high (dx = 12.5 mm), 2 particles per cell per axis; the
# run-out is scale-free in a (Lube et al.), so the a = 1 column is half as long rather
# than twice as high, which keeps the default suite fast.
_COARSE = {"H0": 0.1, "dx": 0.0125, "duration": 0.5}


@pytest.fixture(scope="module")
def coarse_collapses() -> dict:
    return {a: _collapse(a, **_COARSE) for a in (0.5, 1.0)}


def test_sand_deposit_comes_to_rest(coarse_collapses):
    for res in coarse_collapses.values():
        assert res["final_speed"] < 0.05, res
        assert res["slope_points"] >= 3, res


def test_sand_deposit_slope_is_friction_angle(coarse_collapses):
    # The angle is checked on the a = 0.5 column: a short column fails along its flank
    # while its top stays undisturbed (Lube et al. 2005 report the final height equal to
    # the initial one for small a), so the flank comes to rest after slow frictional
    # failure. A taller column is laid down by an inertial flow and can stop below the
    # angle of repose. Measured with this solver at this resolution: a = 0.5: 27.4 deg
    # (top at 0.99 H0); a = 1: 24.5 deg.
    res = coarse_collapses[0.5]
    assert abs(res["angle"] - PHI) < 5.0, res


def test_sand_short_column_keeps_its_height(coarse_collapses):
    # Lube et al. (2005): below a critical aspect ratio part of the initial top surface is
    # left undisturbed, so the deposit's height equals the column's. Allowance 5 %: the
    # elastic compression rho g H / E (1.6 %) and one particle layer (h / H0 = 6 %/2).
    assert coarse_collapses[0.5]["height"] > 0.95, coarse_collapses[0.5]


def test_sand_runout_grows_with_aspect_ratio_as_lube(coarse_collapses):
    lo, hi = coarse_collapses[0.5], coarse_collapses[1.0]
    assert 0 < lo["runout"] < hi["runout"], (lo, hi)
    # Lube et al. (2005): (L_inf - L0)/L0 = 1.2 a below a = 2.3, so doubling a doubles the
    # normalised run-out. Their four materials scatter by about +-15 % about the fit, so
    # the ratio of two measurements is allowed 25 %.
    ratio = hi["runout"] / lo["runout"]
    ratio_ref = lube_planar_runout(1.0) / lube_planar_runout(0.5)
    assert abs(ratio / ratio_ref - 1.0) < 0.25, (ratio, ratio_ref, lo, hi)


@pytest.mark.slow
@pytest.mark.parametrize("phi", [20.0, 30.0, 40.0])
def test_sand_slope_tracks_friction_angle_fine(phi):
    # Twice the resolution (16 cells high); the deposit angle must follow the friction
    # angle across the handbook range of sand (27-45 degrees) and below it.
    res = _collapse(0.5, H0=0.1, dx=0.00625, duration=0.5, phi=phi)
    assert res["final_speed"] < 0.05, res
    assert abs(res["angle"] - phi) < 5.0, res


@pytest.mark.slow
def test_sand_runout_trend_fine():
    # Twice the resolution, and a = 0.5, 1, 2, 3 (3 is in the a^(2/3) regime). Each run-out
    # is compared with Lube et al.'s fit within 20 %, not the ratio of two run-outs: a ratio
    # compounds the deviations of two measurements (two values each within +-15 % of a fit
    # can differ from the fit's ratio by 35 %). The 20 %: the four materials of Lube et al.
    # scatter by about +-15 % about the fit, and the fit's own two branches disagree by 20 %
    # where they meet (a = 2.3: 1.2 a = 2.76 against 1.9 a^(2/3) = 3.31), so near the
    # transition the fit itself is not better than that.
    # Measured 2026-11-22 (sim-validation): run-outs 0.53 (a = 0.5, fit 0.6, -12 %), 2.71
    # (a = 2, fit 2.4, +13 %), 3.39 (a = 3, fit 3.95, -14 %); the a = 2 / a = 0.5 ratio is
    # 5.09 against the fit's 4.0, the compounded -12 % and +13 %.
    res = {
        a: _collapse(a, H0=0.1 if a <= 1 else 0.2, dx=0.00625, duration=0.5 if a <= 1 else 0.8)
        for a in (0.5, 1.0, 2.0, 3.0)
    }
    for r in res.values():
        assert r["final_speed"] < 0.05, r
    runouts = [res[a]["runout"] for a in (0.5, 1.0, 2.0, 3.0)]
    assert all(np.diff(runouts) > 0), res
    for a, r in res.items():
        assert abs(r["runout"] / r["runout_lube"] - 1.0) < 0.20, (a, r)
