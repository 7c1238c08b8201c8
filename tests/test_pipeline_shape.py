"""End to end: a steel rod dropped onto the floor keeps its shape, rubber bounces.

The issue's "what a viewer sees" check for the sim map (materials/simmap.py, yield
rule ``auto``: metal keeps the ratio of impact stress to yield stress). Each case is
the real command (``motionphysics run`` through ``cli.main``) on a prompt-only config
(no ``material:`` block: the kb estimate and the sim map choose every value), a
0.4 m rod (0.048 m thick) whose lowest point starts 0.526 m above a frictional floor,
at a coarse grid (dx = 4.4 cm) so the three runs take ~15 s together on CPU (steel,
at 369 substeps a frame, ~12 s of it; Warp kernels compiled).

Measured (2026-11-22, grid 24, 600 particles): steel keeps every pair distance within
0.1 % and |det F - 1| <= 0.002 after the impact and rebounds to 0.33 of its drop
height; the same steel mapped with the yield-strain rule (``yield_rule='strain'``:
impact/yield 36 instead of 0.70) lands, dents (pair distances change by 5.7 %) and
stays down; plasticine flattens into a 1 cm pancake (pair distances change by
> 200 %); rubber rebounds to 0.42 of its drop height (0.16 since issue 23: simulated at
its kb stiffness instead of 116x softer).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from motionphysics.cli import main

DROP = 0.55  # rod axis height [m]; lowest point 0.55 - 0.024 = 0.526 m
FRAMES = 15  # impact at t = sqrt(2 * 0.526 / 9.8) = 0.33 s (frame 8), rebound peak by frame 14

PROMPTS = {
    "steel": "A steel rod falls onto the floor",
    "plasticine": "A plasticine rod falls onto the floor",
    "rubber": "A rubber rod falls onto the floor and bounces",
}


def _config(prompt: str) -> dict:
    return {
        "scene": {
            "source": "builtin:rod",
            "scale": 0.4,
            "translate": [0, 0, DROP],
            "max_particles": 600,
        },
        "prompt": prompt,
        "sim": {"grid": 24, "frames": FRAMES, "frame_dt": 0.04, "substeps": "auto"},
        "boundary_conditions": [
            {
                "type": "surface_collider",
                "point": [0, 0, 0],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": 0.3,
            },
            {"type": "bounding_box"},
        ],
        "camera": {"radius": 1.5, "look_at": [0, 0, 0.2], "width": 48, "height": 48},
        "optimize": {"prior": "none", "seed": 0},
    }


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("shape")
    out = {}
    for name, prompt in PROMPTS.items():
        cfg = base / f"{name}.yaml"
        cfg.write_text(yaml.safe_dump(_config(prompt)))
        run_dir = base / name
        assert main(["run", str(cfg), "--out", str(run_dir), "--quiet"]) == 0
        tr = np.load(run_dir / "trajectory.npz")
        params = yaml.safe_load((run_dir / "params.json").read_text())  # JSON is YAML
        out[name] = (tr["x"].astype(np.float64), tr["det_F"].astype(np.float64), params)
    return out


def _pair_change(x: np.ndarray) -> float:
    """Largest relative change of the distance between particle pairs, last vs first frame.

    2000 random pairs at least 2 cm apart (closer pairs sit within one grid cell, where
    the interpolation alone moves particles by a fraction of dx = 4.4 cm).
    """
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, x.shape[1], (2, 2000))
    d0 = np.linalg.norm(x[0, i] - x[0, j], axis=1)
    keep = d0 > 0.02
    d1 = np.linalg.norm(x[-1, i] - x[-1, j], axis=1)
    return float(np.max(np.abs(d1[keep] - d0[keep]) / d0[keep]))


def _rebound(x: np.ndarray) -> float:
    """Highest lowest-point height after the first floor contact, over the drop height."""
    zmin = x[:, :, 2].min(axis=1)
    hit = int(np.argmax(zmin < 0.06))  # within ~1 cell of the floor: contact
    assert zmin[hit] < 0.06, "the rod never reached the floor"
    return float(zmin[hit:].max() / zmin[0])


def test_steel_rod_keeps_its_shape_plasticine_does_not(runs):
    x, det_f, params = runs["steel"]
    assert params["class"] == "metal"
    steel = _pair_change(x)
    clay = _pair_change(runs["plasticine"][0])
    assert runs["plasticine"][2]["class"] == "plasticine"
    print(f"pair change steel {steel:.4f} plasticine {clay:.3f}")
    # Steel: measured 0.001. 2 % sits between that and the 5.7 % dent that the yield-strain
    # rule gives on this very drop, and far below the control.
    assert steel < 0.02
    # No lasting volume change either (measured 0.002; elastic ringing after the impact
    # is below 1 % at this stiffness).
    assert np.abs(det_f[-1] - 1.0).max() < 0.02
    # The control visibly deforms: measured > 2 (a 1 cm pancake); 0.5 = half its length.
    assert clay > 0.5
    # And the plasticine stays down: its lowest point ends within a cell of the floor.
    assert runs["plasticine"][0][-1, :, 2].min() < 0.044


def test_rubber_bounces_and_plasticine_does_not(runs):
    x, _, params = runs["rubber"]
    assert params["class"] == "elastic"
    rubber = _rebound(x)
    clay = _rebound(runs["plasticine"][0])
    print(f"rebound rubber {rubber:.3f} plasticine {clay:.3f}")
    # Measured 0.16 (rubber, simulated at its kb stiffness E = 2e6 Pa since issue 23; the
    # 0.42 measured before came from the map simulating it 116x softer; a flat landing
    # also spends energy in bending) and 0.04 (plasticine: it lands and stays).
    assert rubber > 0.1
    assert clay < 0.07
