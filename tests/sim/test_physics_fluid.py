"""Physics validation of the Newtonian fluid (weakly compressible) against experiment.

Dam break: Martin, J.C. & Moyce, W.J. (1952), "Part IV. An experimental study of the
collapse of liquid columns on a rigid horizontal plane", Phil. Trans. R. Soc. Lond. A
244, 312-324. A water column of width a and height 2a (n^2 = 2) collapses along a
horizontal floor; the surge front Z = x / a against T = t sqrt(2 g / a) is compared with
the published points (reference_data.MARTIN_MOYCE_N2_2_A_2_25IN) within 15 %, after
one time shift for the experiment's non-instantaneous release (see below).

The simulation is a thin slab between slip walls (plane flow, as the experiment's
two-dimensional column), slip floor and back wall. Water's viscosity is used as is
(1e-3 Pa s; the flow is inertia-dominated, Re ~ 1e5). The bulk modulus is lowered from
water's 2.2 GPa to a sound speed 10x the largest flow speed 2 sqrt(g 2a) (Mach <= 0.1,
density variations <= 1 %, the standard weakly compressible choice, Monaghan 1994,
J. Comput. Phys. 110, 399), which leaves the incompressible front motion unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from physics_helpers import box_lattice, box_volumes, run
from reference_data import MARTIN_MOYCE_N2_2_A_2_25IN


def _dam_break(cells_per_a: int, t_max: float, a: float = 0.1, ppc: int = 2) -> dict:
    g, rho, mu = 9.8, 1000.0, 1.0e-3
    dx = a / cells_per_a
    pad = 3
    # Grid walls act on nodes i < pad: material is stopped about half a cell beyond the
    # first free node, so the effective wall planes are at (pad - 1/2) dx (see
    # test_physics_granular); the slab fills the space between them.
    wall = (pad - 0.5) * dx
    T_end = t_max
    # Domain: the front must stay clear of the far wall until T_end (Z(T) <= 1.6 T + 1).
    length = a * (1.6 * T_end + 1.5)
    nx = int(math.ceil(length / dx)) + 2 * pad + 3
    ny = 2 + 2 * pad + 1  # 2 free cells: the slab is 3 cells thick between the wall planes
    nz = int(math.ceil(3 * a / dx)) + 2 * pad + 1
    lo = np.array([wall, wall, wall])
    hi = lo + np.array([a, 3 * dx, 2 * a])
    x0 = box_lattice(lo, hi, dx / ppc)
    vol = box_volumes(lo, hi, len(x0))
    u_max = 2.0 * math.sqrt(g * 2 * a)
    c = 10.0 * u_max
    kappa = rho * c * c
    dt = 0.3 * dx / c
    t_scale = math.sqrt(a / (2 * g))  # T = t / t_scale
    frame_substeps = max(1, int(round(0.05 * t_scale / dt)))  # a frame every dT = 0.05
    frames = int(math.ceil(T_end * t_scale / (frame_substeps * dt)))
    r = run(
        x0,
        vol,
        {"class": "newtonian", "mu": mu, "kappa": kappa, "density": rho},
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(nx, ny, nz),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        boundary_conditions=[{"type": "bounding_box", "friction": 0.0, "padding": pad}],
    )
    h = (hi[0] - lo[0]) / round(a / (dx / ppc))
    front = r.x[:, :, 0].max(axis=1) + h / 2 - wall  # leading particle plus its half width
    # Mass is carried by particles (exactly conserved); the fluid's volume follows det F.
    J = np.linalg.det(r.F[-1].astype(np.float64))
    return {"T": r.t / t_scale, "Z": front / a, "J_min": float(J.min()), "J_max": float(J.max())}


def _compare(res: dict, T_max: float) -> dict:
    """Compare the simulated front with Martin & Moyce's points up to ``T_max``.

    The experiment's release is not instantaneous, so its front starts late by an
    unknown time: a single shift ``dT`` (the experiment lags the simulation by dT) is
    measured from the data by least squares in log Z over all points (0.01 steps in
    [0, 1]); ``table`` then holds T, Z_data, Z_sim(T - dT) and the relative deviation.
    """
    data = MARTIN_MOYCE_N2_2_A_2_25IN
    data = data[data[:, 0] <= T_max]
    best = None
    for shift in np.arange(0.0, 1.0 + 1e-9, 0.01):
        z = np.interp(data[:, 0] - shift, res["T"], res["Z"])
        cost = float(np.sum(np.log(z / data[:, 1]) ** 2))
        if best is None or cost < best[0]:
            best = (cost, float(shift), z)
    _, shift, Z_sim = best
    Z_now = np.interp(data[:, 0], res["T"], res["Z"])
    table = np.column_stack([data, Z_sim, Z_sim / data[:, 1] - 1.0])
    return {"shift": shift, "table": table, "unshifted": Z_now / data[:, 1] - 1.0}


# Without a time shift the simulated surge leads the published front by up to +24 % (8
# cells per a) / +22 % (16 cells per a) at T = 1-4 and by 13-16 % up to T = 9.2. Ruled out
# as causes (sim-validation, 2026-11-22): the T scale (T = t sqrt(2 g / a), as digitised),
# the column's extent (cell-centred particles fill [0, a] from the effective wall plane
# (pad - 1/2) dx, from which x is measured), and the front rule (the furthest bin holding
# a full particle layer instead of the furthest particle moves Z by <= 3 %). What remains
# is a time lag of the experiment: the simulation reaches each published Z earlier by
# dT = 0.2-0.3 at T < 1.3 and by a nearly constant 0.4 from T = 2 to 4.4 (16 cells per
# a), the signature of a column that is not released instantaneously. Numerical studies with an
# instantaneous release lead Martin & Moyce in the same way (e.g. the MPS results of
# Koshizuka & Oka 1996, Nucl. Sci. Eng. 123, 421-434), which is commonly attributed to
# the finite time the experiment took to remove the retaining gate/diaphragm. The test
# therefore measures that delay from the data as one time shift dT (see _compare) and
# requires (i) 0 <= dT <= 0.6 (a release delay can only make the experiment late; T = 0.6
# is 33 ms at a = 2.25 in, a gate-removal time of a few hundredths of a second) and (ii)
# every published point within 15 % after that single shift. Measured: dT = 0.33 with
# deviations within -9..+12 % (8 cells per a, T <= 4.5); dT = 0.40 with -9..+10 % (16
# cells per a, T <= 9.2). A single constant shift cannot absorb a wrong front speed over
# T = 0.8-9.2. The slip floor leaves out the experiment's wall friction, which slows a
# thin surge tip (Dressler 1952, J. Res. Natl. Bur. Stand. 49, 217): the simulated late
# front speed dZ/dT is 1.98 (T = 4.4-9.2, 16 cells per a, near the frictionless 2 of
# shallow-water theory) against the experiment's 1.68, which is why the shifted deviation
# grows to +10 % at T = 9.2.
_MAX_RELEASE_SHIFT = 0.6


def _check(cmp: dict) -> None:
    assert 0.0 <= cmp["shift"] <= _MAX_RELEASE_SHIFT, cmp
    assert np.all(np.abs(cmp["table"][:, 3]) < 0.15), cmp


@pytest.fixture(scope="module")
def coarse_dam_break() -> dict:
    # 8 cells across a = 0.1 m, T up to 4.5 (the first 7 published points).
    return _dam_break(cells_per_a=8, t_max=4.5)


def test_dam_break_front_matches_martin_moyce_coarse(coarse_dam_break):
    _check(_compare(coarse_dam_break, 4.5))


@pytest.mark.slow
def test_dam_break_front_matches_martin_moyce_full_range():
    T_max = float(MARTIN_MOYCE_N2_2_A_2_25IN[-1, 0])
    res = _dam_break(cells_per_a=16, t_max=T_max + 0.1)
    _check(_compare(res, T_max))


def test_dam_break_front_advances_and_volume_is_kept(coarse_dam_break):
    # Not a comparison with the experiment: the surge front of the coarse run never moves
    # back, reaches Z > 4 by T = 4 (the column has collapsed), and the fluid's volume
    # (det F of a weakly compressible fluid at Mach <= 0.1: |dV/V| ~ Mach^2) stays within 5 %.
    res = coarse_dam_break
    assert np.all(np.diff(res["Z"]) > -0.05), res["Z"]
    assert np.interp(4.0, res["T"], res["Z"]) > 4.0
    assert 0.95 < res["J_min"] and res["J_max"] < 1.05, res
