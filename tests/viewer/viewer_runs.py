"""Tiny run directories for the viewer tests, made with the real CLI (``simulate``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"


def complete_run_dir(run_dir: Path) -> None:
    """Write what the viewer needs and ``simulate`` does not write yet (``scene.ply``).

    From the same data the pipeline has: the run's own resolved config (run.yaml)
    loaded and prepared as ``run_pipeline`` does; the splat count must match the
    trajectory's ``splat_parent``. Does nothing when the run already has scene.ply.
    """
    from motionphysics.config import load_config
    from motionphysics.scene import load_scene, prepare, write_ply

    if (run_dir / "scene.ply").is_file():
        return
    cfg = load_config(run_dir / "run.yaml")
    sim_scene = prepare(
        load_scene(cfg.scene.source), cfg.scene, cfg.sim, list(cfg.boundary_conditions)
    )
    with np.load(run_dir / "trajectory.npz") as z:
        assert {"F", "splat_parent", "splat_offset"} <= set(z.files), z.files
        parent, offset = z["splat_parent"], z["splat_offset"]
    assert parent.shape == (sim_scene.splats.num,)
    np.testing.assert_array_equal(parent, sim_scene.splat_parent.numpy())
    np.testing.assert_allclose(offset, sim_scene.splat_offset.numpy(), atol=1e-6)
    write_ply(sim_scene.splats, run_dir / "scene.ply")


def make_run(config: Path, out: Path) -> Path:
    env = {
        **os.environ,
        "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src"),
    }
    subprocess.run(
        [sys.executable, "-m", "motionphysics.cli", "--quiet", "simulate", str(config),
         "--out", str(out), "--export-ply"],
        check=True, env=env, capture_output=True, timeout=600,
    )  # fmt: skip
    complete_run_dir(out)
    return out
