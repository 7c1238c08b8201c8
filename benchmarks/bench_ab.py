"""Old against new: ``motionphysics bench mpm`` from two source trees, alternated run by run.

Each round runs one process per tree (``PYTHONPATH=<tree>/src``, this interpreter), the
order alternating between rounds (A B, B A, ...), each reporting the median of
``--repeats`` timed runs after a warm-up. Prints each round's rates and the new / old
ratio, and the median of the per-round ratios: on a shared machine the absolute rates
drift with other load, the ratio of two runs a few seconds apart much less. Both trees
must end at the same centre of mass (``com_z_end``): it is printed per tree.

    git worktree add --detach /tmp/wt-old <commit>; git worktree add --detach /tmp/wt-new <commit>
    MOTIONPHYSICS_CACHE=.cache .venv/bin/python benchmarks/bench_ab.py /tmp/wt-old /tmp/wt-new \\
        --particles 20000 --substeps 100 --threads 2 --rounds 5
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path


def _run(tree: str, args) -> dict:
    exe = Path(sys.executable).with_name("motionphysics")
    env = dict(os.environ, PYTHONPATH=str(Path(tree) / "src"))
    cmd = [str(exe), "bench", "mpm", "--particles", str(args.particles), "--grid", str(args.grid)]
    cmd += ["--substeps", str(args.substeps), "--repeats", str(args.repeats)]
    cmd += ["--threads", str(args.threads), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    for tree in (args.old, args.new):  # compile (or load) each tree's kernels first
        _run(tree, argparse.Namespace(**{**vars(args), "substeps": 2, "repeats": 1}))
    rows = []
    for r in range(args.rounds):
        order = (args.old, args.new) if r % 2 == 0 else (args.new, args.old)
        res = {tree: _run(tree, args) for tree in order}
        a, b = res[args.old], res[args.new]
        ratio = b["particle_substeps_per_s"] / a["particle_substeps_per_s"]
        load = os.getloadavg()[0]
        rows.append((a["particle_substeps_per_s"], b["particle_substeps_per_s"], ratio, load))
        print(
            f"round {r + 1}: old {a['particle_substeps_per_s'] / 1e6:.2f}M "
            f"new {b['particle_substeps_per_s'] / 1e6:.2f}M  new/old {ratio:.3f}  "
            f"(load {load:.1f}; com_z old {a['com_z_end']:.6f} new {b['com_z_end']:.6f})",
            flush=True,
        )
    med = [statistics.median(c[i] for c in rows) for i in range(3)]
    print(
        json.dumps(
            {
                "particles": args.particles,
                "substeps": args.substeps,
                "threads": args.threads,
                "rounds": args.rounds,
                "old_median_M": round(med[0] / 1e6, 3),
                "new_median_M": round(med[1] / 1e6, 3),
                "ratios": [round(c[2], 3) for c in rows],
                "ratio_median": round(med[2], 3),
                "load": [round(c[3], 1) for c in rows],
            }
        )
    )


if __name__ == "__main__":
    main()
