"""Physics against references nobody here tuned, through the command line.

Each case writes a run config (and, for the sand cases, a mesh of the initial shape),
runs ``motionphysics simulate CONFIG --out DIR`` in a subprocess, reads the run's
``trajectory.npz`` and ``params.json`` and measures the motion against a published law or
a closed-form theory, at the grids people run. Prints a markdown table with each case's
grid (cells across the object), substeps per frame and wall time.

Cases (``--cases``, default all):

``rod``      clamped elastic rod (cantilever under its own weight): static tip sag and
             first bending mode against Euler-Bernoulli, within 25 %, >= 4 cells across.
``spheres``  two elastic spheres thrown at each other with gravity 0: they bounce apart,
             momentum is conserved within 1 %, the coefficient of restitution is reported.
``drop``     an elastic sphere dropped on a rigid floor: contact duration against Hertz
             (within a factor of 2) and rebound (coefficient of restitution).
``jelly``    a jelly cube (E = 5e3 Pa) dropped on a plate: it wobbles; the frequency of
             its height oscillation against the same block on a grid twice as fine
             (within 25 %), with the quarter-wave estimate of a block on a rigid base.
``heap``     a cone of sand (friction angle 36 deg, flanks 60 deg, 30 cm across) released
             on the floor: the slope of the heap's flank against the friction angle
             (within 10 deg).
``cone50``   the same sand as a less steep cone (50 deg flanks): flank slope reported.
``lube``     axisymmetric sand columns (r0 = 10 cm) of aspect ratio a = h0/r0 (0.5, 1, 2)
             on the floor: run-out (r_inf - r0)/r0 against Lube et al. (2004) (1.24 a for
             a < 1.7, 1.6 a^(1/2) above; the "ok" column asks 25 %, the tests a factor of
             2) and the final height h_inf/r0 at the centre.
``dambreak`` a water column (width a, height 2a) against a wall collapses along a slip
             floor: surge front x/a against Martin & Moyce (1952) at T = t sqrt(2g/a) in
             [1, 3] (20 %).

    .venv/bin/python benchmarks/bench_references.py [--cases heap,lube] [--work DIR]
        [--quick] [--reuse] [--floor-friction MU] [--lube-a 0.5,1,2] [--json out.json]

``--quick`` runs the small variants the default test suite runs (tests/sim/
test_references.py). The sand cases run on the default ground (no ``boundary_conditions``:
a frictional floor at z = 0, friction 0.3), as a user's config does; ``--floor-friction``
gives them an explicit floor instead.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

G = 9.8
SAND_PHI = 36.0
SAND = {"class": "sand", "density": 1600.0, "theta_fric": SAND_PHI}
ROUGH = math.tan(math.radians(SAND_PHI))
"""A floor as rough as the sand (``--floor-friction 0.7265``; Lube et al. 2004 found the
run-out the same on wood, baize, Plexiglas and sandpaper)."""
CAMERA = {"width": 32, "height": 32}


# --------------------------------------------------------------------------- references


def euler_bernoulli_cantilever(E: float, rho: float, length: float, diameter: float):
    """(tip sag [m], first-mode frequency [Hz]) of a round cantilever under its own weight:
    sag = q L^4 / (8 E I) = 2 rho g L^4 / (E d^2); f1 = (1.8751^2 / 2 pi) sqrt(E I / (rho A
    L^4)) (Timoshenko, Vibration Problems in Engineering, 5.3)."""
    sag = 2.0 * rho * G * length**4 / (E * diameter**2)
    f1 = 1.8751**2 / (2.0 * math.pi) * math.sqrt(E * diameter**2 / (16.0 * rho * length**4))
    return sag, f1


def hertz_contact_time(E: float, nu: float, rho: float, radius: float, speed: float) -> float:
    """Duration [s] of the Hertz impact of an elastic sphere on a rigid flat (Johnson,
    Contact Mechanics, 11.4): 2.87 (m^2 / (R E*^2 v))^(1/5), E* = E / (1 - nu^2)."""
    m = rho * 4.0 / 3.0 * math.pi * radius**3
    e_star = E / (1.0 - nu**2)
    return 2.87 * (m**2 / (radius * e_star**2 * speed)) ** 0.2


def lube_axisymmetric_runout(a: float) -> float:
    """(r_inf - r0)/r0 of a sand cylinder of aspect ratio a (Lube, Huppert, Sparks &
    Hallworth 2004, J. Fluid Mech. 508: 1.24 a for a < 1.7, 1.6 a^(1/2) above)."""
    return 1.24 * a if a < 1.7 else 1.6 * math.sqrt(a)


MARTIN_MOYCE = np.array(
    [
        [0.832, 1.217],
        [1.219, 1.474],
        [1.997, 2.292],
        [2.547, 2.995],
        [3.345, 4.134],
        [4.034, 4.944],
    ]
)
"""Martin & Moyce (1952) Fig. 3, n^2 = 2, a = 2.25 in (T = t sqrt(2g/a), Z = x/a), the
first points of tests/sim/reference_data.MARTIN_MOYCE_N2_2_A_2_25IN."""


# --------------------------------------------------------------------------- measures


def flank_slope(x: np.ndarray, floor: float, dx: float) -> tuple[float, float, int]:
    """(slope [deg], peak height [m], points fitted) of a heap's flank: particle positions
    ``x`` (P, 3) binned by distance from the centre line (mass centre in xy) in rings dx/2
    wide; the top of each ring is its highest particle; a line is fitted to the ring tops
    between 20 % and 80 % of the peak height above the floor."""
    c = x[:, :2].mean(0)
    r = np.hypot(x[:, 0] - c[0], x[:, 1] - c[1])
    z = x[:, 2] - floor
    w = 0.5 * dx
    idx = (r / w).astype(int)
    rs, zs = [], []
    for i in range(int(idx.max()) + 1):
        sel = idx == i
        if sel.sum() >= 3:
            rs.append((i + 0.5) * w)
            zs.append(z[sel].max())
    rs, zs = np.array(rs), np.array(zs)
    top = float(zs.max())
    band = (zs > 0.2 * top) & (zs < 0.8 * top) & (rs > rs[int(np.argmax(zs))])
    if band.sum() < 3:
        return float("nan"), top, int(band.sum())
    k = np.polyfit(rs[band], zs[band], 1)[0]
    return float(math.degrees(math.atan(-k))), top, int(band.sum())


def radial_extent(x: np.ndarray, centre: np.ndarray, q: float = 99.5) -> float:
    """Radius [m] about ``centre`` (xy) within which ``q`` % of the particles lie."""
    return float(np.percentile(np.hypot(x[:, 0] - centre[0], x[:, 1] - centre[1]), q))


def oscillation_frequency(t: np.ndarray, y: np.ndarray) -> float:
    """Mean frequency [Hz] of ``y(t)`` from linearly interpolated crossings of its mean
    (at least three crossings, else nan)."""
    y = y - y.mean()
    s = np.sign(y)
    i = np.nonzero(s[:-1] * s[1:] < 0)[0]
    if i.size < 3:
        return float("nan")
    tc = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
    return float(1.0 / (2.0 * np.mean(np.diff(tc))))


# --------------------------------------------------------------------------- cases


@dataclass
class Run:
    """One simulate run: its directory, params.json, trajectory arrays, stderr, wall time."""

    out: Path
    params: dict
    traj: dict
    err: str
    wall: float

    @property
    def substeps(self) -> int:
        return int(self.params["sim_context"]["substeps"])

    @property
    def dx(self) -> float:
        return float(self.params["scene"]["dx"])

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self.traj["t"], dtype=np.float64)


@dataclass
class Case:
    name: str
    what: str
    configs: Callable[[Path, bool], dict[str, dict]]
    """(work dir, quick) -> {run name: config dict}."""
    measure: Callable[[dict[str, Run], bool], dict]
    """(runs, quick) -> {"measured", "reference", "ok", "across", ...}."""
    extra: dict = field(default_factory=dict)


def _floor(friction: float | None = None, mode: str = "frictional") -> dict:
    bc: dict[str, Any] = {
        "type": "surface_collider",
        "point": [0, 0, 0],
        "normal": [0, 0, 1],
        "mode": mode,
    }
    if friction is not None:
        bc["friction"] = friction
    return bc


# ---- clamped rod


ROD = {"E": 1.0e7, "nu": 0.3, "density": 1100.0}
ROD_LEN, ROD_D, ROD_CLAMP = 0.6, 0.072, 0.06
"""builtin:rod at scale 0.6: 0.6 m along x, 7.2 cm across; the first 6 cm are clamped."""


def _rod_configs(work: Path, quick: bool) -> dict[str, dict]:
    grid = 40 if quick else 48
    x0 = -ROD_LEN / 2
    return {
        "rod": {
            "scene": {
                "source": "builtin:rod",
                "scale": ROD_LEN,
                "translate": [0, 0, 0.35],
                "max_particles": 3000 if quick else 6000,
            },
            "prompt": "A rubber rod held at one end sags and vibrates.",
            "material": {"class": "elastic", **ROD},
            "sim": {
                # tight around the rod and its swing: 0.7 m / grid cells along x
                "domain": [[x0 - 0.05, -0.06, 0.2], [x0 + ROD_LEN + 0.05, 0.06, 0.42]],
                "grid": grid,
                "frames": 40 if quick else 60,
                "frame_dt": 0.02,
                "substeps": "auto",
            },
            "boundary_conditions": [
                {
                    "type": "clamp_grid",
                    "box": [[x0 - 0.1, -0.1, 0.2], [x0 + ROD_CLAMP, 0.1, 0.5]],
                }
            ],
            "camera": CAMERA,
        }
    }


def _rod_measure(runs: dict[str, Run], quick: bool) -> dict:
    r = runs["rod"]
    x = np.asarray(r.traj["x"], dtype=np.float64)
    x0 = -ROD_LEN / 2
    L = ROD_LEN - ROD_CLAMP
    tip = x[0, :, 0] > x0 + ROD_LEN - 0.06
    z = x[:, tip, 2].mean(1)
    drop = z[0] - z
    # released straight, the rod oscillates about its static sag: the mean over whole
    # periods after the first is the static sag (the scheme's damping only shrinks the
    # swing around it)
    f = oscillation_frequency(r.t[1:], drop[1:])
    if math.isfinite(f):
        n = int(round(1.0 / (f * (r.t[1] - r.t[0]))))  # frames per period
        k = max(1, (len(drop) - 1) // n) * n
        sag = float(drop[-k:].mean())
    else:
        sag = float(drop[len(drop) // 2 :].mean())
    E_sim = float(r.params["sim"]["E"])
    sag_ref, f_ref = euler_bernoulli_cantilever(E_sim, ROD["density"], L, ROD_D)
    across = ROD_D / r.dx
    ok = abs(sag / sag_ref - 1) < 0.25 and abs(f / f_ref - 1) < 0.25 and across >= 4
    return {
        "measured": f"sag {sag * 1e3:.1f} mm, f1 {f:.2f} Hz",
        "reference": f"Euler-Bernoulli {sag_ref * 1e3:.1f} mm, {f_ref:.2f} Hz (E_sim {E_sim:.3g})",
        "error": f"{sag / sag_ref - 1:+.0%}, {f / f_ref - 1:+.0%}",
        "ok": bool(ok),
        "across": across,
        "values": {"sag": sag, "f1": f, "sag_ref": sag_ref, "f1_ref": f_ref, "E_sim": E_sim},
    }


# ---- two spheres in zero gravity


BALL = {"class": "elastic", "density": 1100.0, "E": 2.0e6, "nu": 0.45}
BALL_R, BALL_V = 0.1, 1.5


def _spheres_configs(work: Path, quick: bool) -> dict[str, dict]:
    ball = {
        "source": "builtin:sphere",
        "scale": 2 * BALL_R,
        "max_particles": 800 if quick else 2000,
    }
    return {
        "spheres": {
            "prompt": "Two rubber balls collide and bounce apart.",
            "objects": [
                {
                    **ball,
                    "name": "a",
                    "translate": [-0.2, 0, 0.5],
                    "initial_velocity": [BALL_V, 0, 0],
                    "material": BALL,
                },
                {
                    **ball,
                    "name": "b",
                    "translate": [0.2, 0, 0.5],
                    "initial_velocity": [-BALL_V, 0, 0],
                    "material": BALL,
                },
            ],
            "sim": {
                "domain": [[-0.8, -0.3, 0.2], [0.8, 0.3, 0.8]],
                "grid": 40 if quick else 64,
                "frames": 10,
                "frame_dt": 0.04,
                "gravity": [0, 0, 0],
                "substeps": "auto",
            },
            "boundary_conditions": [],
            "camera": CAMERA,
        }
    }


def _spheres_measure(runs: dict[str, Run], quick: bool) -> dict:
    r = runs["spheres"]
    x = np.asarray(r.traj["x"], dtype=np.float64)
    v = np.asarray(r.traj["v"], dtype=np.float64)
    m = np.asarray(r.traj["mass"], dtype=np.float64)
    oid = np.asarray(r.traj["object_id"])
    a, b = oid == 0, oid == 1
    ca, cb = x[:, a, 0].mean(1), x[:, b, 0].mean(1)
    va = (m[a] * v[:, a, 0]).sum(1) / m[a].sum()
    vb = (m[b] * v[:, b, 0]).sum(1) / m[b].sum()
    p = (m[None, :] * v[:, :, 0]).sum(1)
    p_ball = float(m[a].sum()) * BALL_V
    drift = float(np.abs(p - p[0]).max() / p_ball)
    e = float((vb[-1] - va[-1]) / (2 * BALL_V))
    apart = bool(np.all(ca < cb) and va[-1] < 0 < vb[-1])
    ok = apart and drift < 0.01
    return {
        "measured": f"bounce apart: {'yes' if apart else 'NO'}; momentum drift {drift:.2%}; restitution {e:.2f}",
        "reference": "momentum conserved (< 1 % of one ball's)",
        "error": f"{drift:.2%}",
        "ok": ok,
        "across": 2 * BALL_R / r.dx,
        "values": {"restitution": e, "momentum_drift": drift, "apart": apart},
    }


# ---- elastic sphere dropped on a rigid floor


DROP = {"class": "elastic", "density": 1100.0, "E": 1.0e6, "nu": 0.45}
DROP_R, DROP_H = 0.1, 0.2
"""A soft rubber ball 20 cm across released with its lowest point 0.2 m above the floor."""


def _drop_configs(work: Path, quick: bool) -> dict[str, dict]:
    return {
        "drop": {
            "scene": {
                "source": "builtin:sphere",
                "scale": 2 * DROP_R,
                "translate": [0, 0, DROP_H + DROP_R],
                "max_particles": 1500 if quick else 4000,
            },
            "prompt": "A soft rubber ball is dropped onto a hard floor and bounces.",
            "material": DROP,
            "sim": {
                "domain": [[-0.2, -0.2, 0.0], [0.2, 0.2, DROP_H + 2 * DROP_R + 0.02]],
                "grid": 32 if quick else 48,
                "frames": 90,
                "frame_dt": 0.004,
                "substeps": "auto",
            },
            "boundary_conditions": [_floor(0.3), {"type": "bounding_box"}],
            "camera": CAMERA,
        }
    }


def _drop_measure(runs: dict[str, Run], quick: bool) -> dict:
    r = runs["drop"]
    t = r.t
    x = np.asarray(r.traj["x"], dtype=np.float64)
    v = np.asarray(r.traj["v"], dtype=np.float64)
    m = np.asarray(r.traj["mass"], dtype=np.float64)
    vz = (m[None, :] * v[:, :, 2]).sum(1) / m.sum()
    # the floor's force is m (dvz/dt + g): contact while it pushes, from the frame the
    # centre's fall first slows to the frame its rise stops gaining speed
    acc = np.gradient(vz, t) + G
    v_imp = math.sqrt(2 * G * DROP_H)
    push = acc > 0.1 * (
        v_imp / hertz_contact_time(DROP["E"], DROP["nu"], DROP["density"], DROP_R, v_imp)
    )
    if not push.any():
        return {"measured": "no contact", "reference": "", "ok": False, "across": 0.0, "error": ""}
    first = int(np.argmax(push))
    last = first + int(np.argmax(~push[first:])) if (~push[first:]).any() else len(t) - 1
    duration = float(t[last] - t[first])
    v_in = float(-vz[: first + 1].min())
    v_out = float(vz[first:].max())
    e = v_out / v_in
    E_sim = float(r.params["sim"]["E"])
    tc = hertz_contact_time(E_sim, DROP["nu"], DROP["density"], DROP_R, v_in)
    ok = 0.5 < duration / tc < 2.0 and e > 0.3
    return {
        "measured": f"contact {duration * 1e3:.0f} ms, rebound e = {e:.2f} (impact {v_in:.2f} m/s)",
        "reference": f"Hertz {tc * 1e3:.0f} ms (E_sim {E_sim:.3g})",
        "error": f"x{duration / tc:.2f}",
        "ok": bool(ok),
        "across": 2 * DROP_R / r.dx,
        "values": {"contact": duration, "hertz": tc, "restitution": e, "v_impact": v_in},
        "bottom": float(x[:, :, 2].min()),
    }


# ---- jelly cube


JELLY = {"class": "elastic", "density": 1050.0, "E": 5.0e3, "nu": 0.45}
JELLY_L = 0.12


def _jelly_config(grid: int, particles: int) -> dict:
    return {
        "scene": {
            "source": "builtin:cube",
            "scale": JELLY_L,
            "translate": [0, 0, JELLY_L / 2 + 0.03],
            "max_particles": particles,
        },
        "prompt": "A wobbly jelly cube is dropped on a plate and wobbles.",
        "material": JELLY,
        "sim": {
            "domain": [[-0.12, -0.12, 0.0], [0.12, 0.12, 0.18]],
            "grid": grid,
            "frames": 50,
            "frame_dt": 0.01,
            "substeps": "auto",
        },
        "boundary_conditions": [_floor(0.5), {"type": "bounding_box"}],
        "camera": CAMERA,
    }


def _jelly_configs(work: Path, quick: bool) -> dict[str, dict]:
    out = {"jelly": _jelly_config(24, 3000)}
    if not quick:
        out["jelly_fine"] = _jelly_config(48, 20000)
    return out


def _height_series(r: Run) -> np.ndarray:
    x = np.asarray(r.traj["x"], dtype=np.float64)
    return np.percentile(x[:, :, 2], 99, axis=1) - x[:, :, 2].min(1)


def _jelly_measure(runs: dict[str, Run], quick: bool) -> dict:
    res = {}
    for name, r in runs.items():
        h = _height_series(r)
        land = int(np.argmin(h[: len(h) // 2]))  # the first squash
        f = oscillation_frequency(r.t[land:], h[land:])
        res[name] = (f, float(h.min() / h[0]), r)
    f, squash, r = res["jelly"]
    E_sim = float(r.params["sim"]["E"])
    # lowest vertical mode of a block standing on its base with a free top: a quarter wave
    # of the bar speed sqrt(E / rho) over its height (free sides; the laterally constrained
    # P-wave modulus would give sqrt(M / E) = 1.9x more)
    f_bar = math.sqrt(E_sim / JELLY["density"]) / (4 * JELLY_L)
    f_fine, squash_fine, _ = res.get("jelly_fine", (f_bar, float("nan"), None))
    ref = "fine grid (2x)" if "jelly_fine" in res else "quarter-wave bar"
    ok = abs(f / f_fine - 1) < 0.25 and squash < 0.9
    return {
        "measured": f"wobbles (squash to {squash:.2f}); f {f:.2f} Hz",
        "reference": f"{ref} {f_fine:.2f} Hz (quarter-wave bar {f_bar:.2f} Hz)",
        "error": f"{f / f_fine - 1:+.0%}",
        "ok": bool(ok),
        "across": JELLY_L / r.dx,
        "values": {
            "f": f,
            "f_fine": f_fine,
            "f_bar": f_bar,
            "squash": squash,
            "squash_fine": squash_fine,
        },
    }


# ---- sand heap


def _cone_mesh(path: Path, radius: float, height: float) -> str:
    import trimesh

    trimesh.creation.cone(radius=radius, height=height, sections=64).export(path)
    return str(path)


def _cylinder_mesh(path: Path, radius: float, height: float) -> str:
    import trimesh

    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=64)
    mesh.apply_translation([0, 0, height / 2])
    mesh.export(path)
    return str(path)


FLOOR: dict[str, float | None] = {"friction": None}
"""The sand cases' floor: ``None`` leaves ``boundary_conditions`` out, so the run gets the
default ground (a frictional floor at z = 0, friction 0.3) as a user's config does;
``--floor-friction MU`` gives an explicit floor of that Coulomb coefficient (and walls)."""


def _sand_config(source: str, grid: int, frames: int, particles: int, prompt: str) -> dict:
    return {
        "scene": {"source": source, "max_particles": particles},
        "prompt": prompt,
        "material": SAND,
        "sim": {"grid": grid, "frames": frames, "frame_dt": 0.04, "substeps": "auto"},
        **(
            {}
            if FLOOR["friction"] is None
            else {"boundary_conditions": [_floor(FLOOR["friction"]), {"type": "bounding_box"}]}
        ),
        "camera": CAMERA,
    }


HEAP_R = 0.15


def _heap_configs(work: Path, quick: bool, slope: float = 60.0, name: str = "heap") -> dict:
    h = HEAP_R * math.tan(math.radians(slope))
    src = _cone_mesh(work / f"cone{slope:.0f}.stl", HEAP_R, h)
    return {
        name: _sand_config(
            src,
            32 if quick else 48,
            25,
            8000 if quick else 20000,
            "A cone of sand settles into a heap.",
        )
    }


def _heap_measure(runs: dict[str, Run], quick: bool) -> dict:
    (r,) = runs.values()
    x = np.asarray(r.traj["x"], dtype=np.float64)
    slope, top, n = flank_slope(x[-1], 0.0, r.dx)
    slope0, top0, _ = flank_slope(x[0], 0.0, r.dx)
    v_end = float(np.abs(np.asarray(r.traj["v"])[-1]).max())
    ok = abs(slope - SAND_PHI) <= 10.0
    return {
        "measured": f"flank {slope:.1f} deg (from {slope0:.0f}), height {top / top0:.2f} of initial, v_end {v_end:.2f} m/s",
        "reference": f"friction angle {SAND_PHI:.0f} deg (10 deg)",
        "error": f"{slope - SAND_PHI:+.1f} deg",
        "ok": bool(ok),
        "across": 2 * HEAP_R / r.dx,
        "values": {"slope": slope, "height_ratio": top / top0, "fit_points": n, "v_end": v_end},
    }


# ---- Lube column


LUBE_R0 = 0.1
LUBE = {"a": (0.5, 1.0, 2.0), "quick": (1.0,)}
"""Aspect ratios of the Lube columns (``--lube-a`` changes ``a``)."""


def _lube_configs(work: Path, quick: bool) -> dict[str, dict]:
    out = {}
    for a in LUBE["quick"] if quick else LUBE["a"]:
        src = _cylinder_mesh(work / f"column_a{a:g}.stl", LUBE_R0, a * LUBE_R0)
        frames = int(math.ceil((0.6 + 0.25 * a) / 0.04))
        out[f"lube_a{a:g}"] = _sand_config(
            src,
            32 if quick else 48,
            frames,
            8000 if quick else 20000,
            "A column of sand collapses.",
        )
    return out


def _lube_measure(runs: dict[str, Run], quick: bool) -> dict:
    rows, ok, vals = [], True, {}
    across = []
    for name, r in runs.items():
        a = float(name.split("_a")[1])
        x = np.asarray(r.traj["x"], dtype=np.float64)
        c = x[0, :, :2].mean(0)
        r0 = radial_extent(x[0], c)
        rf = radial_extent(x[-1], c)
        run_out = (rf - r0) / r0
        ref = lube_axisymmetric_runout(a)
        rr = np.hypot(x[-1, :, 0] - c[0], x[-1, :, 1] - c[1])
        h_inf = float(np.percentile(x[-1, rr < 0.5 * r0, 2], 99))
        h0 = float(np.percentile(x[0, :, 2], 99.5))
        err = run_out / ref - 1
        ok &= abs(err) < 0.25
        rows.append(
            f"a={a:g}: {run_out:.2f} vs {ref:.2f} ({err:+.0%}), h_inf/r0 {h_inf / r0:.2f} (h0/r0 {h0 / r0:.2f})"
        )
        vals[name] = {
            "a": a,
            "runout": run_out,
            "lube": ref,
            "h_inf_r0": h_inf / r0,
            "h0_r0": h0 / r0,
        }
        across.append(2 * r0 / r.dx)
    return {
        "measured": "; ".join(rows),
        "reference": "Lube 2004: 1.24 a (a<1.7), 1.6 a^1/2 (25 %)",
        "error": "",
        "ok": bool(ok),
        "across": min(across),
        "values": vals,
    }


# ---- dam break


DAM_A = 0.1


def _dambreak_configs(work: Path, quick: bool) -> dict[str, dict]:
    grid = 48 if quick else 64
    return {
        "dambreak": {
            "scene": {
                # builtin:column is 0.5 x 0.5 x 1 at scale 1: a x a x 2a of water in the
                # corner (x = 0 is the back wall, the slab is a thick between slip walls)
                "source": "builtin:column",
                "scale": 2 * DAM_A,
                "translate": [DAM_A / 2, DAM_A / 2, DAM_A],
                "max_particles": 8000 if quick else 20000,
            },
            "prompt": "A column of water collapses along the floor.",
            "material": {"class": "newtonian", "density": 1000.0, "mu": 1.0e-3, "kappa": 2.0e9},
            "sim": {
                "domain": [[0.0, 0.0, 0.0], [8 * DAM_A, DAM_A, 2.5 * DAM_A]],
                "grid": grid,
                "frames": 30,
                "frame_dt": 0.01,
                "substeps": "auto",
            },
            "boundary_conditions": [{"type": "bounding_box"}],
            "camera": CAMERA,
        }
    }


def _dambreak_measure(runs: dict[str, Run], quick: bool) -> dict:
    r = runs["dambreak"]
    x = np.asarray(r.traj["x"], dtype=np.float64)
    front = np.percentile(x[:, :, 0], 99.5, axis=1)
    T = r.t * math.sqrt(2 * G / DAM_A)
    Z = front / DAM_A
    sel = (MARTIN_MOYCE[:, 0] >= 1.0) & (MARTIN_MOYCE[:, 0] <= 3.0)
    Zs = np.interp(MARTIN_MOYCE[sel, 0], T, Z)
    err = Zs / MARTIN_MOYCE[sel, 1] - 1
    worst = float(err[np.argmax(np.abs(err))])
    ok = bool(np.all(np.abs(err) < 0.2))
    pts = ", ".join(f"T={t:.1f}: {z:.2f}" for t, z in zip(MARTIN_MOYCE[sel, 0], Zs, strict=True))
    ref = ", ".join(f"{z:.2f}" for z in MARTIN_MOYCE[sel, 1])
    return {
        "measured": f"front x/a {pts}",
        "reference": f"Martin & Moyce 1952: {ref} (20 %)",
        "error": f"worst {worst:+.0%}",
        "ok": ok,
        "across": DAM_A / r.dx,
        "values": {
            "T": MARTIN_MOYCE[sel, 0].tolist(),
            "Z": Zs.tolist(),
            "Z_ref": MARTIN_MOYCE[sel, 1].tolist(),
        },
    }


CASES: dict[str, Case] = {
    "rod": Case(
        "rod", "clamped elastic rod, E = 1e7 Pa (sag, first mode)", _rod_configs, _rod_measure
    ),
    "spheres": Case("spheres", "two elastic spheres, g = 0", _spheres_configs, _spheres_measure),
    "drop": Case("drop", "elastic sphere dropped on a rigid floor", _drop_configs, _drop_measure),
    "jelly": Case("jelly", "jelly cube, E = 5e3 Pa", _jelly_configs, _jelly_measure),
    "heap": Case(
        "heap", "sand cone (60 deg flanks) released, phi = 36 deg", _heap_configs, _heap_measure
    ),
    "cone50": Case(
        "cone50",
        "sand cone (50 deg flanks) released, phi = 36 deg",
        lambda w, q: _heap_configs(w, q, 50.0, "cone50"),
        _heap_measure,
    ),
    "lube": Case("lube", "Lube sand columns, phi = 36 deg", _lube_configs, _lube_measure),
    "dambreak": Case(
        "dambreak", "water dam break (slip floor)", _dambreak_configs, _dambreak_measure
    ),
}


# --------------------------------------------------------------------------- running


def _load(out: Path, err: str, wall: float) -> Run:
    params = json.loads((out / "params.json").read_text())
    with np.load(out / "trajectory.npz") as d:
        traj = {k: d[k] for k in d.files}
    return Run(out, params, traj, err, wall)


def simulate(config: dict, out: Path, reuse: bool = False) -> Run:
    """Write ``config`` next to ``out`` and run ``motionphysics simulate`` on it (``reuse``:
    measure a complete run already in ``out`` made from the same config instead)."""
    import yaml

    out.parent.mkdir(parents=True, exist_ok=True)
    path = out.parent / f"{out.name}.yaml"
    text = yaml.safe_dump(config, sort_keys=False)
    if reuse and path.exists() and path.read_text() == text and (out / "params.json").exists():
        return _load(out, "", float("nan"))
    path.write_text(text)
    cmd = [sys.executable, "-m", "motionphysics", "simulate", str(path), "--out", str(out)]
    cmd += ["--force", "--quiet"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return _load(out, proc.stderr, wall)


def run_case(case: Case, work: Path, quick: bool = False, reuse: bool = False) -> dict:
    """Simulate every config of ``case`` and measure; returns the measure's dict plus
    grid, substeps and wall-time columns."""
    d = work / case.name
    d.mkdir(parents=True, exist_ok=True)
    configs = case.configs(d, quick)
    runs = {name: simulate(cfg, d / name, reuse) for name, cfg in configs.items()}
    res = case.measure(runs, quick)
    main = runs[next(iter(runs))]
    res.update(
        case=case.name,
        what=case.what,
        grid=[int(cfg["sim"]["grid"]) for cfg in configs.values()],
        dx=[r.dx for r in runs.values()],
        substeps=[r.substeps for r in runs.values()],
        wall_s=[round(float(r.params.get("wall_time_s", r.wall)), 1) for r in runs.values()],
        simulate_s=[round(float(r.params["timings"]["simulate"]), 1) for r in runs.values()],
        particles=[int(r.params["scene"]["particles"]) for r in runs.values()],
        warnings=[ln for r in runs.values() for ln in r.err.splitlines() if "than asked" in ln],
        E_sim=(main.params.get("sim") or {}).get("E"),
    )
    return res


def table(results: list[dict]) -> str:
    head = (
        "| case | grid (cells across) | substeps/frame | wall [s] | measured | reference | error | ok |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in results:
        grid = ", ".join(f"{g}" for g in r["grid"]) + f" ({r['across']:.1f})"
        lines.append(
            f"| {r['what']} | {grid} | {', '.join(map(str, r['substeps']))} | "
            f"{', '.join(f'{w:.0f}' for w in r['wall_s'])} | {r['measured']} | {r['reference']} | "
            f"{r['error']} | {'yes' if r['ok'] else '**no**'} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--work", default=None, help="keep the runs here (default: a temp dir)")
    ap.add_argument("--quick", action="store_true", help="the small variants the tests run")
    ap.add_argument("--reuse", action="store_true", help="measure complete runs left in --work")
    ap.add_argument(
        "--floor-friction",
        type=float,
        default=None,
        help="an explicit floor for the sand cases, e.g. 0.7265 (= tan 36 deg); default: the "
        "default ground (friction 0.3)",
    )
    ap.add_argument(
        "--lube-a", default=None, help="aspect ratios of the Lube columns, e.g. 0.5,1,2"
    )
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    if a.floor_friction is not None:
        FLOOR["friction"] = a.floor_friction
    if a.lube_a is not None:
        LUBE["a"] = tuple(float(v) for v in a.lube_a.split(","))
    names = [c for c in a.cases.split(",") if c]
    unknown = [c for c in names if c not in CASES]
    if unknown:
        ap.error(f"unknown cases {unknown}; expected some of {list(CASES)}")
    tmp = None
    if a.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_references_")
        work = Path(tmp.name)
    else:
        work = Path(a.work)
    results = []
    try:
        for name in names:
            res = run_case(CASES[name], work, a.quick, a.reuse)
            results.append(res)
            print(
                f"{name}: {res['measured']} | {res['reference']} | ok={res['ok']}", file=sys.stderr
            )
    finally:
        if tmp is not None:
            tmp.cleanup()
    print(table(results))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
