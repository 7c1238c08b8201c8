"""Cost of one refinement iteration with the motion prior against a forward simulation of
the same frames (the issue's speed bar: at most 2.5x).

One config (the capsule mesh of ``bench_prior_direction.py``, elastic, 16 frames, grid
24, 1,500 particles): ``motionphysics simulate`` ``--sim-repeats`` times (the median of
their ``simulate`` timings, the forward rollout of every frame: one run alone scatters by
+-20 % on a shared machine) and ``motionphysics run --prior motion --loss lmd`` for
``--iters`` iterations (each iteration's ``time.total`` in ``log.jsonl``: the rollout
with its tape, the features, the prior, the backward; the first iteration, which loads
and allocates, is not counted). Boosting is 1, so each iteration supervises every frame
the forward run produces. Prints JSON.

    python benchmarks/bench_motion_iteration.py --iters 4
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_prior_direction import PAIRS, _config, _mesh, _scenes  # noqa: E402


def _cli(*args: str) -> None:
    exe = Path(sys.executable).with_name("motionphysics")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = subprocess.run([str(exe), *args], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise SystemExit(f"motionphysics {' '.join(args)} failed: {r.stderr[-600:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=4)
    ap.add_argument("--prior-path", default=None)
    ap.add_argument("--sim-repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        _mesh(tmp)
        scene = _scenes(tmp, ["mesh"])["capsule (mesh)"]
        pair = PAIRS["elastic"]
        cfg = _config(scene, pair, pair["up"].format(obj="capsule"), {"type": "lmd"}, args.iters, 0)
        cfg["optimize"]["boost"] = 1
        if args.prior_path:
            cfg["optimize"]["prior_path"] = args.prior_path
        path = tmp / "config.yaml"
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        sims = []
        for _ in range(max(1, args.sim_repeats)):
            _cli("simulate", str(path), "--out", str(tmp / "sim"), "--force", "--quiet")
            sims.append(json.loads((tmp / "sim" / "params.json").read_text())["timings"])
        _cli("run", str(path), "--out", str(tmp / "run"), "--force", "--quiet")
        log = [json.loads(x) for x in (tmp / "run" / "log.jsonl").read_text().splitlines()]
    it = [r["time"]["total"] for r in log[1:]] or [log[0]["time"]["total"]]
    mean = sum(it) / len(it)
    sim_s = statistics.median(t["simulate"] for t in sims)
    res = {
        "forward_simulate_s": sim_s,
        "forward_simulate_runs_s": [t["simulate"] for t in sims],
        "iteration_s": mean,
        "iterations_timed": len(it),
        "ratio": mean / sim_s,
        "bar": 2.5,
        "frames_per_iteration": len(log[0]["frames"]),
        "parts_s": {k: sum(r["time"][k] for r in log[1:]) / max(1, len(log) - 1)
                    for k in ("simulate", "loss", "backward")},
    }  # fmt: skip
    # the parts against the forward: the rollout with its tape, its backward
    res["taped_rollout_over_forward"] = res["parts_s"]["simulate"] / sim_s
    res["backward_over_forward"] = res["parts_s"]["backward"] / sim_s
    res["pass"] = res["ratio"] <= res["bar"]
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
