"""MPM throughput side by side: motionphysics (Warp) vs Taichi and Genesis, one scene.

Runs, in one invocation and one after the other on the same machine,

- ``motionphysics bench mpm --json`` (the project's venv, this interpreter),
- ``benchmarks/peers/taichi_mpm.py`` (Taichi CPU MLS-MPM written for the same scene),
- ``benchmarks/peers/genesis_mpm.py`` (Genesis' own MPM solver, CPU backend),

the last two with the peers' separate environment (``benchmarks/setup_peers.sh``,
default ``benchmarks/.venv-peers``). Each reports particle-substeps per second (median
of ``--repeats`` runs after a warm-up that excludes compilation); this script prints a
Markdown table with the ratios and the end-of-run centre of mass of each engine (the
three integrate the same scene, so it must agree: a cheap check that the timed work is
the same physics). With ``--rounds R`` the engines are alternated R times (one process
per engine per round); the table gives, per engine, the median over the rounds of the
per-round medians (and the best), and ``ours / engine`` is the median over rounds of the
ratio within each round (both engines measured minutes apart, under the same load), so a
load spike in one round does not decide the ratio.

    python benchmarks/bench_mpm.py --particles 20000 --substeps 100 --repeats 5 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _last_json(text: str) -> dict:
    # Engines may print banners on stdout; the result is the last JSON line.
    for line in reversed(text.strip().splitlines()):
        line = line.strip()
        if line.startswith("{") and line.endswith("}"):
            return json.loads(line)
    raise ValueError("no JSON result in output")


def _run(cmd: list[str], env: dict | None = None, timeout: float = 1800) -> dict:
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=ROOT)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:]
        return {"error": f"exit {proc.returncode}: " + " | ".join(tail)}
    try:
        return _last_json(proc.stdout)
    except ValueError as err:
        return {"error": str(err)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument(
        "--threads", type=int, default=2, help="CPU threads of every engine (default 2)"
    )
    ap.add_argument("--peers-python", default=str(HERE / ".venv-peers" / "bin" / "python"))
    ap.add_argument("--engines", default="motionphysics,taichi,genesis")
    ap.add_argument("--backward", action="store_true", help="also time our forward+backward")
    ap.add_argument("--json-out", default=None, help="write all results to this JSON file")
    args = ap.parse_args()

    common = [
        "--particles",
        str(args.particles),
        "--grid",
        str(args.grid),
        "--substeps",
        str(args.substeps),
        "--repeats",
        str(args.repeats),
    ]
    env = dict(os.environ)
    env.setdefault("MOTIONPHYSICS_CACHE", str(ROOT / ".cache"))
    engines = [e.strip() for e in args.engines.split(",") if e.strip()]
    peers_ok = Path(args.peers_python).exists()
    cmds = {
        "motionphysics": [
            sys.executable,
            "-m",
            "motionphysics",
            "bench",
            "mpm",
            *common,
            "--threads",
            str(args.threads),
            "--json",
            *(["--backward"] if args.backward else []),
        ],
        "taichi": [
            args.peers_python,
            str(HERE / "peers" / "taichi_mpm.py"),
            *common,
            "--threads",
            str(args.threads),
        ],
        "genesis": [
            args.peers_python,
            str(HERE / "peers" / "genesis_mpm.py"),
            *common,
            "--threads",
            str(args.threads),
        ],
    }
    rounds: dict[str, list[dict]] = {name: [] for name in engines}
    load: list[float] = []
    t0 = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    for _ in range(max(1, args.rounds)):
        for name in engines:
            if name != "motionphysics" and not peers_ok:
                res = {
                    "error": f"peers environment missing ({args.peers_python}); "
                    "run benchmarks/setup_peers.sh"
                }
            else:
                load.append(os.getloadavg()[0])
                res = _run(cmds[name], env)
            rounds[name].append(res)
    load.append(os.getloadavg()[0])
    t1 = time.strftime("%H:%M:%S UTC", time.gmtime())

    def _ok(name: str) -> list[dict]:
        return [r for r in rounds[name] if "error" not in r]

    summary: dict[str, dict] = {}
    for name in engines:
        good = _ok(name)
        if not good:
            summary[name] = {"error": rounds[name][-1].get("error", "no result")}
            continue
        rates = [r["particle_substeps_per_s"] for r in good]
        summary[name] = {
            **good[-1],
            "rates_per_round": rates,
            "particle_substeps_per_s": statistics.median(rates),
            "best_particle_substeps_per_s": max(rates),
        }
    ours_rounds = rounds.get("motionphysics", [])
    for name in engines:
        if name == "motionphysics" or "error" in summary[name]:
            continue
        per_round = [
            o["particle_substeps_per_s"] / e["particle_substeps_per_s"]
            for o, e in zip(ours_rounds, rounds[name], strict=True)
            if "error" not in o and "error" not in e
        ]
        summary[name]["ours_over_engine_per_round"] = per_round
        if per_round:
            summary[name]["ours_over_engine"] = statistics.median(per_round)

    print(
        f"MPM benchmark: {args.particles} particles requested, grid {args.grid}^3, "
        f"{args.substeps} substeps/run, {args.repeats} runs (+warm-up) per process, "
        f"{args.threads} threads, {args.rounds} alternated round(s), {t0} - {t1}, "
        f"1-min load average {min(load):.1f}-{max(load):.1f}\n"
    )
    print(
        "| engine | version | particles | particle-substeps/s (median of rounds) | per round "
        "| ours / engine (median of per-round ratios) | per round | z_com end [m] |"
    )
    print("|---|---|---:|---:|---|---:|---|---:|")
    for name in engines:
        r = summary[name]
        if "error" in r:
            print(f"| {name} | - | - | unavailable: {r['error']} | - | - | - | - |")
            continue
        version = r.get("version") or r.get("warp", "-")
        per = " ".join(f"{x / 1e6:.3f}M" for x in r["rates_per_round"])
        ratio = f"{r['ours_over_engine']:.2f}" if "ours_over_engine" in r else "1.00"
        ratios = " ".join(f"{x:.2f}" for x in r.get("ours_over_engine_per_round", []))
        print(
            f"| {name} | {version} | {r['particles']} | {r['particle_substeps_per_s']:,.0f} "
            f"| {per} | {ratio} | {ratios} | {r['com_z_end']:.6f} |"
        )
    mp = summary.get("motionphysics", {})
    if args.backward and "backward_particle_substeps_per_s" in mp:
        print(
            f"\nmotionphysics forward+backward (last round): "
            f"{mp['backward_particle_substeps_per_s']:,.0f} "
            f"particle-substeps/s; forward+backward time = {mp['backward_over_forward']:.2f} x forward; "
            f"peak RSS {mp['peak_rss_mb']:.0f} MB"
        )
    best = {"summary": summary, "rounds": rounds, "load_average": load, "start": t0, "end": t1}
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(best, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
