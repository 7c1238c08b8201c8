"""Physics validation of the plastic return maps (von Mises, Herschel-Bulkley).

1. von Mises (metal; von Mises 1913; radial return as in Simo & Hughes 1998,
   "Computational Inelasticity", sec. 3.3): a block stretched by an initial velocity
   field and left free oscillates about its rest shape when the stress stays below the
   yield stress (no plastic strain at all), and keeps a permanent stretch when the
   stress exceeds it.
2. Herschel-Bulkley (non-Newtonian fluid): a mound whose base stress rho g H stays below
   the uniaxial yield stress tau_Y does not slump; one far above it flows and slumps as
   Pashias et al. (1996, J. Rheol. 40, 1179: slump theory after Murata 1984) predict.

Materials are given directly in simulation units.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from physics_helpers import box_lattice, box_volumes, run
from reference_data import slump_fraction


def _von_mises(F: np.ndarray, E: float, nu: float) -> np.ndarray:
    """Von Mises equivalent Kirchhoff stress [Pa] of StVK-Hencky elasticity for F (..., 3, 3).

    tau = 2 mu eps + lambda tr(eps) I in principal log strains eps = log(sigma(F)); the
    equivalent stress sqrt(3/2) ||dev tau|| equals the uniaxial stress of a bar, so the
    paper's yield condition ||s|| > sqrt(2/3) tau_Y reads sigma_vm > tau_Y.
    """
    mu = E / (2 * (1 + nu))
    sig = np.linalg.svd(F.astype(np.float64), compute_uv=False)
    eps = np.log(sig)
    dev = eps - eps.mean(axis=-1, keepdims=True)
    return math.sqrt(1.5) * 2 * mu * np.linalg.norm(dev, axis=-1)


def _stretch_block(tau_Y: float, cells: int = 32, ppc: int = 2) -> dict:
    """Free metal cube (side 6/32 m) given v_x = rate (x - x_c); no gravity, no walls."""
    E, nu, rho = 1.0e5, 0.3, 1000.0
    dx = 1.0 / cells
    side = 6.0 / 32.0
    lo = np.full(3, 0.5 - side / 2)
    hi = lo + side
    x0 = box_lattice(lo, hi, dx / ppc)
    vol = box_volumes(lo, hi, len(x0))
    # Axial mode of the block as a free-free bar: f = c / (2 L), c = sqrt(E / rho).
    c_bar = math.sqrt(E / rho)
    period = 2 * side / c_bar
    # Stretch rate giving a peak strain of about 2 % if elastic (strain amplitude of a
    # linear velocity field is rate / omega); the stress scale is then E * 0.02.
    rate = 0.02 * 2 * math.pi / period
    v0 = np.zeros_like(x0)
    v0[:, 0] = rate * (x0[:, 0] - 0.5)
    c_p = math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho))
    dt = 0.3 * dx / c_p
    frame_substeps = max(1, int(round(period / 40 / dt)))
    frames = int(math.ceil(5 * period / (frame_substeps * dt)))
    n = cells + 1
    r = run(
        x0,
        vol,
        {"class": "metal", "E": E, "nu": nu, "tau_Y": tau_Y, "density": rho},
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(n, n, n),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        gravity=(0.0, 0.0, 0.0),
        velocity=v0,
    )
    std0 = r.x[0, :, 0].std()
    strain = r.x[:, :, 0].std(axis=1) / std0 - 1.0  # nominal axial strain of the block
    late = r.t >= 3 * period  # the last two periods: oscillation averages out
    return {
        "vm_max": float(_von_mises(r.F, E, nu).max()),
        "peak": float(strain.max()),
        "late_mean": float(strain[late].mean()),
        "late_amplitude": float(np.ptp(strain[late]) / 2),
        "ep_max": float(r.ep[-1].max()),
        "stress_scale": E * 0.02,
    }


@pytest.fixture(scope="module")
def elastic_run() -> dict:
    # A yield stress far above anything the block reaches: the elastic reference run.
    return _stretch_block(tau_Y=1.0e9)


def test_von_mises_below_yield_recovers(elastic_run):
    peak_vm = elastic_run["vm_max"]
    assert 0.3 * elastic_run["stress_scale"] < peak_vm < 3 * elastic_run["stress_scale"], (
        elastic_run
    )
    # 10 % above the largest von Mises stress of the elastic run: nothing may yield ...
    below = _stretch_block(tau_Y=1.1 * peak_vm)
    assert below["ep_max"] == 0.0, below
    # ... and the block oscillates about its rest shape: the late mean strain is zero up to
    # a small fraction of the peak (the window spans whole periods of the axial mode).
    assert abs(below["late_mean"]) < 0.1 * below["peak"], below


def test_von_mises_yield_threshold_is_calibrated(elastic_run):
    # 10 % below the elastic run's peak von Mises stress, the same loading must yield:
    # together with the test above this brackets the yield stress within [0.9, 1.1] of
    # the von Mises criterion sigma_vm = tau_Y (a sqrt(2/3) or sqrt(3) slip would fail).
    above = _stretch_block(tau_Y=0.9 * elastic_run["vm_max"])
    assert above["ep_max"] > 0.0, above


def test_von_mises_above_yield_leaves_permanent_strain(elastic_run):
    yielded = _stretch_block(tau_Y=0.1 * elastic_run["vm_max"])
    # Far above yield the stretch stays: the residual strain is most of the peak strain
    # (the elastic part that springs back is at most tau_Y / E, a fraction of a percent)
    # and far larger than the residual oscillation.
    assert yielded["ep_max"] > 0.0
    assert yielded["late_mean"] > 0.5 * yielded["peak"], yielded
    assert yielded["late_mean"] > 3 * yielded["late_amplitude"], yielded
    assert yielded["late_mean"] > 10 * abs(elastic_run["late_mean"]), (yielded, elastic_run)


def _mound(
    tau_ratio: float, cells: int = 32, ppc: int = 2, duration: float = 0.4, eta: float = 10.0
) -> dict:
    """Herschel-Bulkley cylinder (H = D = 8/64 m) released on a sticky floor.

    ``tau_ratio`` is tau_y / (rho g H) for the material's shear yield stress
    tau_y = tau_Y / sqrt(3) (von Mises: the return map yields at ||s|| = sqrt(2/3) tau_Y,
    i.e. at tau_Y in uniaxial stress and tau_Y / sqrt(3) in simple shear).

    The slump theory (Murata 1984; Pashias et al. 1996) takes the stress in the mound to
    be the vertical stress rho g (H - z) alone (no lateral stress) and lets the material
    yield where half of it, the largest shear stress of that uniaxial state, reaches the
    yield stress: yield at sigma_zz = 2 tau_y(theory). Our von Mises material in that
    stress state yields at sigma_zz = tau_Y = sqrt(3) tau_y. The theory is therefore
    evaluated with tau_y(theory) = tau_Y / 2, the value at which its yield criterion
    coincides with the material's in the stress state it assumes (using tau_Y / sqrt(3)
    would credit the theory's material with a 2/sqrt(3) = 1.15x higher uniaxial yield
    stress than the simulated one). No slump is predicted when tau_Y >= rho g H.

    ``eta`` is the return map's plastic viscosity; in simple shear the flow rule reads
    tau = tau_Y / sqrt(3) + (eta / 2) gamma_dot (n = 1), a consistency K = eta / 2 [Pa s].
    """
    mu, kappa, rho, g = 2.0e4, 1.0e5, 1000.0, 9.8
    size = 0.5
    dx = size / cells
    floor = 3 * dx
    H = 8 * size / 32
    radius = H / 2
    h = dx / ppc
    lo = np.array([size / 2 - radius, size / 2 - radius, floor])
    pts = box_lattice(lo, lo + np.array([2 * radius, 2 * radius, H]), h)
    pts = pts[np.hypot(pts[:, 0] - size / 2, pts[:, 1] - size / 2) <= radius]
    vol = np.full(len(pts), h**3)
    tau_Y = math.sqrt(3.0) * tau_ratio * rho * g * H
    c = math.sqrt((kappa + 4.0 / 3.0 * mu) / rho)
    dt = 0.3 * dx / c
    frame_substeps = max(1, int(round(0.01 / dt)))
    frames = int(math.ceil(duration / (frame_substeps * dt)))
    n = cells + 1
    r = run(
        pts,
        vol,
        {
            "class": "non_newtonian",
            "mu": mu,
            "kappa": kappa,
            "tau_Y": tau_Y,
            "eta": eta,
            "n": 1.0,
            "density": rho,
        },
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=(n, n, n),
        dt=dt,
        substeps_per_frame=frame_substeps,
        frames=frames,
        boundary_conditions=[
            {"type": "bounding_box", "padding": 3},
            {
                "type": "surface_collider",
                "point": [0, 0, floor],
                "normal": [0, 0, 1],
                "mode": "sticky",
            },
        ],
    )
    top = np.quantile(r.x[:, :, 2], 0.99, axis=1) + h / 2 - floor  # robust top of the mound
    height = top / top[0]
    late = r.t >= 0.75 * duration
    rad = np.hypot(r.x[:, :, 0] - size / 2, r.x[:, :, 1] - size / 2).max(axis=1) + h / 2
    return {
        "slump": float(1.0 - height[late].mean()),
        "slump_predicted": slump_fraction(tau_Y / 2.0, rho, g, H),
        "spread": float(rad[-1] / rad[0] - 1.0),
        "ep_max": float(r.ep[-1].max()),
        "elastic_sag": rho * g * H / (2 * mu),
    }


def test_herschel_bulkley_mound_below_yield_stays_put():
    # tau' = 1: tau_Y = sqrt(3) rho g H, 1.7x the no-slump threshold tau_Y = rho g H of
    # the slump theory; the margin covers the dynamic overshoot of releasing the mound
    # under gravity from rest.
    res = _mound(tau_ratio=1.0)
    assert res["slump_predicted"] == 0.0
    # What remains is the elastic sag rho g H / (2 mu) ~ 3 % and its oscillation.
    assert res["slump"] < 0.1, res
    assert res["spread"] < 0.05, res


def test_herschel_bulkley_mound_above_yield_flows():
    # tau' = 0.1: the slump theory predicts a slump of 52 % of the height (see _mound).
    res = _mound(tau_ratio=0.1)
    assert res["ep_max"] > 0.1, res  # it yielded and flowed
    assert res["spread"] > 0.2, res
    # The slump theory is quasi-static and one-dimensional (no inertia, no radial stress);
    # their measurements scatter about it by ~10 %. Allow 25 % for the released, dynamic
    # collapse on a coarse grid (8 cells over H). Measured: 0.48 (-9 %); the fine slow
    # test below measures 0.57 at twice the resolution: the coarse value is not converged.
    assert abs(res["slump"] / res["slump_predicted"] - 1.0) < 0.25, res


@pytest.mark.slow
def test_herschel_bulkley_slump_follows_pashias_fine():
    # The theory is quasi-static: Pashias et al. lift the cylinder slowly, and the final
    # shape of a yield-stress fluid depends on how much kinetic energy the collapse carries
    # past the static shape. With the former eta = 1 (K = 0.5 Pa s) the collapse Reynolds
    # number rho sqrt(g H) H / K is ~280 and the released mound overshoots: tau' = 0.1
    # slumped 0.66 (fine) / 0.55 (coarse). With eta = 10 (K = 5 Pa s, Re ~ 28, still a
    # paste-like consistency) it slumps 0.57 / 0.48 and has stopped by 0.4 s. The slow
    # limit is not reached: eta = 50 (coarse) gives 0.40 and still creeps at 3 s, so the
    # remaining deviation reflects inertia, the coarse sticky floor layer, and the
    # theory's one-dimensional stress state; the theory's own data scatter ~10 %.
    # Measured 2026-11-22 (eta = 10, 64 cells): tau' = 0.1: 0.565 vs 0.523 (+8 %);
    # tau' = 0.2: 0.327 vs 0.286 (+14 %); tau' = 0.3: 0.132 vs 0.140 (-6 %).
    # (Before the theory's yield stress was matched to the material's in uniaxial stress,
    # see _mound, the predictions were 0.478 / 0.233 / 0.093.)
    for tau_ratio in (0.1, 0.2, 0.3):
        res = _mound(tau_ratio=tau_ratio, cells=64, duration=0.5)
        assert abs(res["slump"] - res["slump_predicted"]) < 0.25 * res["slump_predicted"] + 0.03, (
            tau_ratio,
            res,
        )
