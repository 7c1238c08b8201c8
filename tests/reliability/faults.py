"""SIGKILL at random points of ``run`` and ``fit``, then ``--resume``: the final
parameters must be those of an uninterrupted run.

Cases (tiny sizes; every one a real command-line process):

- ``run``: no prior, no refinement (scene -> kb material -> simulate -> render);
- ``run-refine``: the refinement stage with a cheap loss (``trajectory_match`` against a
  trajectory made by ``simulate``), 4 iterations;
- ``run-lmd``: ``--prior cogvideox --prior-path DIR --loss lmd --iters 3`` with the tiny
  seeded CogVideoX pipeline of ``tests/priors/tiny_pipelines.py`` (the learnable motion
  extractor, its AdamW state and EMA are checkpointed);
- ``fit``: system identification against the same trajectory, 4 iterations.

For each case an uninterrupted run is timed first; each kill then comes at a time drawn
uniformly from [0, 0.9 x that duration] (seeded), so it lands anywhere: during the imports
(nothing written yet), in the scene / material stages, between an iteration's log line
and its checkpoint, during simulation, rendering or the writing of the outputs. The
process is killed with SIGKILL (no handler runs), the stage it was in is read from
``params.json``, and the same command with ``--resume`` must finish with status 0 and
the same ``params``, ``sim`` values, optimised theta (``checkpoint.pt``) and trajectory
as the uninterrupted run, compared bit for bit.

Run as a script for the figures of BENCHMARKS.md ("Reliability")::

    PYTHONPATH=src python tests/reliability/faults.py --kills 2 --log-kills 2 \\
        --seed 1 --out /tmp/faults.json
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
from test_resume import TINY  # noqa: E402

CASES = ("run", "run-refine", "run-lmd", "fit")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "motionphysics", "--quiet", *args]


def prepare(root: Path) -> dict[str, list[str]]:
    """Write the configs (and the tiny prior) under ``root``; the command of each case
    without ``--out``."""
    root.mkdir(parents=True, exist_ok=True)
    true = {**TINY, "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3}}
    (root / "true.yaml").write_text(yaml.safe_dump(true))
    ref = root / "ref"
    if (
        not (ref / "params.json").is_file()
        or json.loads((ref / "params.json").read_text())["partial"]
    ):
        subprocess.run(
            _cli("simulate", str(root / "true.yaml"), "--out", str(ref), "--force"),
            check=True,
            env=_env(),
        )
    traj = str(ref / "trajectory.npz")
    start = {
        **TINY,
        "material": {"class": "elastic", "density": 1000.0, "E": 2.0e9, "nu": 0.3},
        "optimize": {"params": ["E"], "iterations": 4, "boost": 1, "lr": 0.3, "warmup": 0},
    }
    (root / "start.yaml").write_text(yaml.safe_dump(start))
    refine = json.loads(json.dumps(start))
    refine["optimize"]["losses"] = [{"type": "trajectory_match", "reference": traj}]
    (root / "refine.yaml").write_text(yaml.safe_dump(refine))
    (root / "plain.yaml").write_text(yaml.safe_dump(TINY))
    prior = root / "tiny-cogvideox"
    if not (prior / "model_index.json").is_file():
        sys.path.insert(0, str(ROOT / "tests" / "priors"))
        from tiny_pipelines import write_tiny_cogvideox

        write_tiny_cogvideox(prior)
    return {
        "run": ["run", str(root / "plain.yaml")],
        "run-refine": ["run", str(root / "refine.yaml")],
        "run-lmd": [
            "run",
            str(root / "plain.yaml"),
            "--prior",
            "cogvideox",
            "--prior-path",
            str(prior),
            "--loss",
            "lmd",
            "--iters",
            "3",
        ],
        "fit": ["fit", str(root / "start.yaml"), "--reference", traj, "--iters", "4"],
    }


def final_state(run_dir: Path) -> dict[str, Any]:
    """What must not depend on a kill: params, sim values, theta, trajectory."""
    p = json.loads((run_dir / "params.json").read_text())
    out: dict[str, Any] = {"params": p["params"], "sim": p["sim"], "status": p["status"]}
    ck = run_dir / "checkpoint.pt"
    if ck.is_file():
        import torch

        data = torch.load(ck, map_location="cpu", weights_only=False)
        out["theta"] = {k: v.double().numpy().tolist() for k, v in data["theta"].items()}
        out["next_iteration"] = data["next_iteration"]
        out["loss_states"] = _flatten_states(data.get("loss_states") or [])
        out["history_loss"] = [r.get("loss") for r in data["history"]]
    with np.load(run_dir / "trajectory.npz") as z:
        out["x"] = z["x"].copy()
        out["F"] = z["F"].copy()
    return out


def _flatten_states(states) -> dict[str, np.ndarray]:
    """Every tensor of the losses' state_dicts (extractor, EMA, AdamW moments)."""
    import torch

    flat: dict[str, np.ndarray] = {}

    def walk(obj, key):
        if isinstance(obj, torch.Tensor):
            flat[key] = obj.detach().cpu().double().numpy()
        elif isinstance(obj, dict):
            for k, v in obj.items():
                walk(v, f"{key}.{k}")
        elif isinstance(obj, (list, tuple)):
            for i, v in enumerate(obj):
                walk(v, f"{key}[{i}]")

    walk(states, "loss")
    return flat


def differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Names of the quantities that are not bit-identical between two final states."""
    bad = []
    for key in ("params", "sim", "status", "theta", "next_iteration", "history_loss"):
        if a.get(key) != b.get(key):
            bad.append(key)
    for key in ("x", "F"):
        if not np.array_equal(a[key], b[key]):
            bad.append(key)
    la, lb = a.get("loss_states") or {}, b.get("loss_states") or {}
    if set(la) != set(lb) or any(not np.array_equal(la[k], lb[k]) for k in la):
        bad.append("loss_states")
    return bad


def _stage(run_dir: Path) -> str:
    p = run_dir / "params.json"
    if not p.is_file():
        return "run.yaml only" if (run_dir / "run.yaml").is_file() else "nothing written"
    try:
        return json.loads(p.read_text()).get("stage") or "?"
    except ValueError:
        return "params.json torn"


def uninterrupted(cmd: list[str], out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(_cli(*cmd, "--out", str(out), "--force"), check=True, env=_env())
    return time.perf_counter() - t0


def kill_and_resume(
    cmd: list[str], out: Path, delay: float, *, after_log_lines: int | None = None
) -> dict[str, Any]:
    """SIGKILL ``cmd`` after ``delay`` s (with ``after_log_lines``: ``delay`` s after
    ``log.jsonl`` reached that many lines, i.e. inside the optimisation), then
    ``--resume`` it; what happened."""
    proc = subprocess.Popen(
        _cli(*cmd, "--out", str(out)),
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    if after_log_lines is not None:
        log = out / "log.jsonl"
        while proc.poll() is None:
            if log.is_file() and len(log.read_text().splitlines()) >= after_log_lines:
                break
            time.sleep(0.01)
    try:
        proc.wait(timeout=delay)
        killed = False
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        killed = True
    stage = _stage(out) if killed else "finished first"
    log = out / "log.jsonl"
    logged = len(log.read_text().splitlines()) if log.is_file() else 0
    r = subprocess.run(
        _cli(*cmd, "--out", str(out), "--resume"), env=_env(), capture_output=True, text=True
    )
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("motionphysics:")]
    return {
        "delay_s": round(delay, 2),
        "killed": killed,
        "stage_at_kill": stage,
        "log_lines_at_kill": logged,
        "resume_status": r.returncode,
        "resume_message": lines[0] if lines else "",
        "resume_stderr_tail": r.stderr.strip().splitlines()[-3:] if r.returncode else [],
    }


ITERATIONS = {"run-refine": 4, "run-lmd": 3, "fit": 4}
"""Iterations of the optimising cases (for kills inside the optimisation)."""


def run_faults(
    root: Path, kills: int, seed: int = 0, cases=CASES, log_kills: int = 0
) -> dict[str, Any]:
    """For each case: one uninterrupted run, ``kills`` kill-and-resume runs at random
    times, and (optimising cases) ``log_kills`` more at a random moment of up to 0.15 s
    after a random iteration's log line (between a log line and its checkpoint, in the
    next iteration's simulation, render, loss or backward pass)."""
    rng = random.Random(seed)
    commands = prepare(root)
    report: dict[str, Any] = {"seed": seed, "kills_per_case": kills, "cases": {}}
    for name in cases:
        cmd = commands[name]
        ref_dir = root / f"{name}-uninterrupted"
        duration = uninterrupted(cmd, ref_dir)
        ref = final_state(ref_dir)
        trials = []
        for k in range(kills + (log_kills if name in ITERATIONS else 0)):
            out = root / f"{name}-kill{k}"
            if out.exists():
                import shutil

                shutil.rmtree(out)
            # 0.9: a run under other load may be faster than the timed one
            if k < kills:
                trial = kill_and_resume(cmd, out, rng.uniform(0.0, 0.9 * duration))
            else:
                line = rng.randint(1, ITERATIONS[name] - 1)
                trial = kill_and_resume(cmd, out, rng.uniform(0.0, 0.15), after_log_lines=line)
                trial["after_log_lines"] = line
            if trial["resume_status"] == 0:
                trial["not_identical"] = differences(ref, final_state(out))
            trial["survived"] = trial["resume_status"] == 0 and not trial.get("not_identical")
            trials.append(trial)
            print(name, json.dumps(trial), flush=True)
        report["cases"][name] = {
            "command": " ".join(["motionphysics", *cmd]),
            "uninterrupted_s": round(duration, 1),
            "trials": trials,
            "survived": sum(t["survived"] for t in trials),
        }
    return report


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kills", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="/tmp/mp-faults")
    ap.add_argument("--out", default=None)
    ap.add_argument("--log-kills", type=int, default=0)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    a = ap.parse_args()
    rep = run_faults(Path(a.root), a.kills, a.seed, a.cases, a.log_kills)
    text = json.dumps(rep, indent=1)
    if a.out:
        Path(a.out).write_text(text + "\n")
    print(text)
