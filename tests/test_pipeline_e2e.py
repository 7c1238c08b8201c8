"""`motionphysics run` end to end on a tiny config: every file of the run directory.

One real subprocess run (the installed entry point), then eval / simulate / re-run of
run.yaml in-process against it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from motionphysics.cli import main
from motionphysics.config import load_config

DATA = Path(__file__).parent / "data"
TINY = DATA / "pipeline_tiny.yaml"
FRAMES = 8


def _env():
    env = dict(os.environ)
    env.setdefault("MOTIONPHYSICS_CACHE", str(Path(__file__).resolve().parents[1] / ".cache"))
    return env


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("e2e") / "run"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "motionphysics",
            "run",
            str(TINY),
            "--out",
            str(out),
            "--export-ply",
        ],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "video:" in proc.stdout and "material:" in proc.stdout
    return out


def test_run_directory_files(run_dir):
    for name in (
        "run.yaml",
        "params.json",
        "trajectory.npz",
        "video.mp4",
        "metrics.json",
        "report.html",
        "plots/reference.png",
        "plots/slice_row.png",
        "plots/slice_col.png",
        "plots/energy.png",
    ):
        assert (run_dir / name).is_file(), name
    assert not [p.name for p in run_dir.iterdir() if p.name.startswith(".")]  # no temporaries


def test_params_json(run_dir):
    p = json.loads((run_dir / "params.json").read_text())
    assert p["partial"] is False and p["status"] == "complete"
    assert p["class"] == "elastic" and 500 < p["density"] < 3000
    assert set(p["params"]) == {"E", "nu"} and p["params"]["nu"] == pytest.approx(0.4)
    assert {"E", "nu", "density"} <= set(p["sim"])
    assert p["sim"]["E"] <= p["params"]["E"]  # the sim map only compresses stiffness
    prov = p["provenance"]
    assert prov["backend"] == "kb" and prov["estimate"]["material"]["class"] == "elastic"
    assert prov["sources"] == {"density": "kb", "E": "kb", "nu": "config"}
    assert prov["overrides"] == {"nu": pytest.approx(0.4)}
    # Issue 23: a substitution is listed only where it can be seen; here E is simulated
    # as asked or compressed where it cannot be seen, and then nothing is listed, and
    # nothing is said on stderr (sim_context records it)
    if p["sim"]["E"] < p["params"]["E"] and p["sim_context"]["visible_changes"]:
        assert [(c["field"], c["kind"]) for c in prov["clamps"]] == [("E", "mapped to simulation")]
    else:
        assert prov["clamps"] == [] and p["sim_context"]["visible_changes"] == []
    assert p["history"] == [] and p["sim_context"]["substeps"] >= 1
    assert {"load scene", "estimate material", "simulate", "render"} <= set(p["timings"])


def test_run_yaml_is_resolved(run_dir):
    cfg = load_config(run_dir / "run.yaml")
    p = json.loads((run_dir / "params.json").read_text())
    assert cfg.material.class_ == "elastic" and cfg.material.E == pytest.approx(p["params"]["E"])
    assert cfg.material.nu == pytest.approx(0.4) and cfg.material.density == pytest.approx(
        p["density"]
    )
    raw = yaml.safe_load((run_dir / "run.yaml").read_text())
    assert raw["optimize"]["seed"] == 0 and "torch" in raw["versions"]
    assert cfg.camera.radius > 0 and "radius" in raw["camera"]  # auto-framed view written in


def test_trajectory_and_motion(run_dir):
    with np.load(run_dir / "trajectory.npz") as z:
        x, t, det_F, v, mass = z["x"], z["t"], z["det_F"], z["v"], z["mass"]
    P = x.shape[1]
    assert x.shape == (FRAMES, P, 3) and x.dtype == np.float32 and P > 100
    assert t.shape == (FRAMES,) and np.allclose(np.diff(t), 0.04)
    assert det_F.shape == (FRAMES, P) and v.shape == (FRAMES, P, 3) and mass.shape == (P,)
    assert np.isfinite(x).all()
    drop = x[0, :, 2].mean() - x[:, :, 2].mean(1).min()
    assert drop > 0.05  # it fell (free fall over 0.15 m before touching down)
    assert x[:, :, 2].min() > -0.02  # and the ground stopped it


def test_video_decodes(run_dir):
    from motionphysics.io.video import read_video

    v = read_video(run_dir / "video.mp4")
    assert v.shape == (FRAMES, 48, 64, 3)
    assert np.abs(v[0].astype(int) - v[-1].astype(int)).mean() > 1.0  # the picture changed


def test_metrics_and_eval(run_dir, capsys):
    m = json.loads((run_dir / "metrics.json").read_text())
    assert len(m["kinetic_energy"]) == FRAMES and len(m["potential_energy"]) == FRAMES
    assert m["max_kinetic_energy"] > 0 and 0.5 < m["final_height_ratio"] < 1.5
    assert "volume_ratio" in m and m["centroid_drop"] > 0.05
    (run_dir / "metrics.json").unlink()
    assert main(["eval", str(run_dir)]) == 0
    e = json.loads((run_dir / "metrics.json").read_text())
    # eval recomputes the trajectory diagnostics identically and adds the video metrics
    for k in (
        "kinetic_energy",
        "potential_energy",
        "final_height_ratio",
        "spread_ratio",
        "rebound_ratio",
    ):
        assert e[k] == m[k], k
    assert e["ecms"] > 0 and e["clipsim"] is None and e["motion_adherence"]["score"] is not None
    out = capsys.readouterr().out
    assert "ECMS" in out and "extent final/initial" in out


def test_report_and_splats(run_dir):
    html = (run_dir / "report.html").read_text()
    assert "rubber ball" in html and "video.mp4" in html and "plots/slice_row.png" in html
    assert "http://" not in html and "https://" not in html
    from motionphysics.scene.ply import read_ply

    files = sorted((run_dir / "splats").glob("*.ply"))
    assert len(files) == FRAMES
    first, last = read_ply(files[0]), read_ply(files[-1])
    assert first.num == last.num and float((first.means - last.means).norm(dim=1).mean()) > 0.05


def test_simulate_with_params_reproduces(run_dir, tmp_path):
    out = tmp_path / "sim"
    assert (
        main(
            [
                "--quiet",
                "simulate",
                str(TINY),
                "--params",
                str(run_dir / "params.json"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    for name in ("trajectory.npz", "video.mp4", "params.json", "run.yaml"):
        assert (out / name).is_file()
    a, b = np.load(run_dir / "trajectory.npz")["x"], np.load(out / "trajectory.npz")["x"]
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_rerun_of_run_yaml_reproduces(run_dir, tmp_path):
    out = tmp_path / "again"
    assert main(["--quiet", "run", str(run_dir / "run.yaml"), "--out", str(out)]) == 0
    a, b = np.load(run_dir / "trajectory.npz")["x"], np.load(out / "trajectory.npz")["x"]
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_refuses_existing_run(run_dir, capsys):
    assert main(["run", str(TINY), "--out", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert "--force" in err and len(err.strip().splitlines()) == 1
