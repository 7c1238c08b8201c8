"""``motionphysics fit``: recovery of known parameters on the MPM simulator, the command
line (outputs, bad input, refusing to overwrite), and kill-and-resume."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from motionphysics.cli import main
from motionphysics.optimize.sysid import CASES, case_config, run_case


@pytest.mark.parametrize("name", ["elastic", "metal", "newtonian", "sand"])
def test_recovers_parameters_from_a_far_start(name, tmp_path):
    r = run_case(name, tmp_path, size="fast")
    # Tolerances are the issue's: E 10 % (simulation value), nu 0.05, tau_Y 20 %,
    # mu 20 %, theta_fric 3 degrees; each start is a factor 5 (or 5.5 degrees) away.
    assert r["ok"], f"{name}: recovered {r['final_sim']} vs true {r['true_sim']} ({r['errors']})"
    for n, (kind, _) in CASES[name].tolerance.items():
        start_err = abs(r["start_sim"][n] - r["true_sim"][n]) / (
            abs(r["true_sim"][n]) if kind == "rel" else 1
        )
        assert start_err > r["errors"][n]["error"] * 2, (
            "the fit must actually move towards the truth"
        )


@pytest.mark.slow
@pytest.mark.parametrize("name", ["elastic", "metal", "newtonian", "sand"])
def test_recovers_parameters_full_size(name, tmp_path):
    r = run_case(name, tmp_path, size="full", iterations=40)
    assert r["ok"], f"{name}: recovered {r['final_sim']} vs true {r['true_sim']} ({r['errors']})"


def _write_cfg(path: Path, material: dict, **optimize) -> Path:
    data = case_config(CASES["elastic"], material, "fast", **optimize)
    data["sim"]["frames"] = 4
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    """A reference made by ``motionphysics simulate`` with the true elastic material."""
    d = tmp_path_factory.mktemp("fitref")
    cfg = _write_cfg(d / "true.yaml", CASES["elastic"].true)
    assert main(["--quiet", "simulate", str(cfg), "--out", str(d / "ref")]) == 0
    start = _write_cfg(
        d / "start.yaml",
        {"density": 1000.0, "E": 1.0e10, "nu": 0.25},
        params=["E"],
        lr=0.3,
        lr_per_param={},
    )
    return d, start


def test_fit_command_writes_the_run_directory(reference_run, tmp_path, capsys):
    d, start = reference_run
    out = tmp_path / "fit"
    assert (
        main(
            [
                "fit",
                str(start),
                "--reference",
                str(d / "ref" / "trajectory.npz"),
                "--out",
                str(out),
                "--iters",
                "3",
            ]
        )
        == 0
    )
    for f in (
        "params.json",
        "log.jsonl",
        "checkpoint.pt",
        "trajectory.npz",
        "video.mp4",
        "run.yaml",
        "plots/loss.png",
        "plots/params.png",
        "plots/slice.png",
    ):
        assert (out / f).is_file(), f
    params = json.loads((out / "params.json").read_text())
    assert params["partial"] is False and params["fit"]["iterations_run"] == 3
    assert params["fit"]["loss"] == "trajectory_match"
    assert set(params["params"]) == {"E", "nu"} and "E" in params["sim"]
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert params["history"] == log
    # both stages in the log: the global candidates first (negative iterations, the
    # start first), then the gradient stage's iterations 0, 1, 2
    glob = [r for r in log if r["stage"] == "global"]
    grad = [r for r in log if r["stage"] == "gradient"]
    assert glob and glob == log[: len(glob)] and glob[0]["params"]["E"] == pytest.approx(1e10)
    its = [r["iteration"] for r in glob]
    assert its == sorted(its) and its[-1] < 0
    assert [r["iteration"] for r in grad] == [0, 1, 2]
    best = min(glob, key=lambda r: r["loss"] if r["loss"] is not None else float("inf"))
    assert grad[0]["params"]["E"] == pytest.approx(best["params"]["E"], rel=1e-5)
    assert params["fit"]["global"]["candidates"] == len(glob)
    # the global stage lands within a grid spacing of the truth from 1e10 (the elastic
    # range in global_points log steps; the refine round splits that)
    from motionphysics.materials.catalog import spec

    ps = spec("elastic", "E")
    step = (ps.high / ps.low) ** (1.0 / 9)
    true_E = CASES["elastic"].true["E"]
    assert true_E / step < grad[-1]["params"]["E"] < true_E * step
    with np.load(out / "trajectory.npz") as z, np.load(d / "ref" / "trajectory.npz") as ref:
        assert z["x"].shape == ref["x"].shape
    assert "fit:" in capsys.readouterr().out

    # an output directory holding a run is refused without --resume / --force
    assert (
        main(
            [
                "fit",
                str(start),
                "--reference",
                str(d / "ref" / "trajectory.npz"),
                "--out",
                str(out),
                "--iters",
                "1",
            ]
        )
        == 2
    )
    assert "holds another run" in capsys.readouterr().err
    assert (
        main(
            [
                "--quiet",
                "fit",
                str(start),
                "--reference",
                str(d / "ref" / "trajectory.npz"),
                "--out",
                str(out),
                "--iters",
                "1",
                "--force",
                "--no-global",
            ]
        )
        == 0
    )
    # --no-global: the gradient stage alone, from the config's material
    (line,) = (out / "log.jsonl").read_text().splitlines()
    assert json.loads(line)["stage"] == "gradient"
    assert json.loads(line)["params"]["E"] == pytest.approx(1e10, rel=1e-5)


def test_fit_to_a_video_reference(reference_run, tmp_path):
    d, start = reference_run
    out = tmp_path / "fitv"
    assert (
        main(
            [
                "--quiet",
                "fit",
                str(start),
                "--reference",
                str(d / "ref" / "video.mp4"),
                "--out",
                str(out),
                "--iters",
                "2",
            ]
        )
        == 0
    )
    params = json.loads((out / "params.json").read_text())
    grad = [r for r in params["history"] if r["stage"] == "gradient"]
    assert params["fit"]["loss"] == "video_match" and len(grad) == 2
    assert all(r["grad_norm"]["total"] > 0 for r in grad)
    # the global stage scored its candidates on the rendered video too
    glob = [r for r in params["history"] if r["stage"] == "global"]
    assert len(glob) >= 2 and all(r["loss"] is not None and r["loss"] > 0 for r in glob)


def test_bad_references_are_refused_naming_both_sides(reference_run, tmp_path, capsys):
    d, start = reference_run
    with np.load(d / "ref" / "trajectory.npz") as z:
        x = z["x"]
    cases = {
        "frames.npz": ({"x": x[:3]}, "reference has 3 frames but .* sim.frames is 4"),
        "particles.npz": (
            {"x": x[:, :10]},
            "reference has 10 particles but the scene of .* prepares",
        ),
        "res.npz": (
            {"frames": np.zeros((4, 40, 40, 3), np.uint8)},
            r"reference is 40x40 pixels but .* camera is 48x48",
        ),
        "empty.npz": ({"y": np.zeros(3)}, "no 'frames' .* or 'x'"),
    }
    for name, (arrays, pattern) in cases.items():
        np.savez(tmp_path / name, **arrays)
        rc = main(
            ["fit", str(start), "--reference", str(tmp_path / name), "--out", str(tmp_path / "o")]
        )
        err = capsys.readouterr().err
        assert rc == 2, name
        # one error line; the start (E = 1e10 at 16 substeps) may also carry the sim map's
        # one-line warning of a visible change, said before the reference is checked
        errors = [ln for ln in err.strip().splitlines() if not ln.startswith("warning:")]
        assert len(errors) == 1, err
        import re

        assert re.search(pattern, err), (name, err)
    assert main(["fit", str(start), "--reference", str(tmp_path / "nope.npz")]) == 2


def _fit_cmd(start, ref, out, *extra):
    return [
        sys.executable,
        "-m",
        "motionphysics",
        "--quiet",
        "fit",
        str(start),
        "--reference",
        str(ref),
        "--out",
        str(out),
        *extra,
    ]


@pytest.mark.slow  # three CLI subprocesses: ~25 s idle; the loop's own SIGKILL test is fast
def test_killed_fit_resumes_to_the_same_parameters(reference_run, tmp_path):
    d, start = reference_run
    ref = d / "ref" / "trajectory.npz"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2] / "src")}
    iters = "10"
    subprocess.run(
        _fit_cmd(start, ref, tmp_path / "a", "--iters", iters), check=True, env=env, timeout=600
    )
    proc = subprocess.Popen(_fit_cmd(start, ref, tmp_path / "b", "--iters", iters), env=env)
    log = tmp_path / "b" / "log.jsonl"
    deadline = time.time() + 300

    def gradient_lines():
        lines = log.read_text().splitlines() if log.exists() else []
        return [x for x in lines if '"stage": "gradient"' in x]

    while time.time() < deadline and proc.poll() is None:
        if len(gradient_lines()) >= 3:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the fit finished before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert 3 <= len(gradient_lines()) < 10
    subprocess.run(
        _fit_cmd(start, ref, tmp_path / "b", "--iters", iters, "--resume"),
        check=True,
        env=env,
        timeout=600,
    )
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["theta"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["theta"]
    for n in a:
        # Warp on CPU and torch run the same operations in the same order: bit-identical.
        assert torch.equal(a[n], b[n]), (n, a[n], b[n])
    pa = json.loads((tmp_path / "a" / "params.json").read_text())["params"]
    pb = json.loads((tmp_path / "b" / "params.json").read_text())["params"]
    assert pa == pb
