"""System identification benchmark: recovery of known parameters, ``full`` vs ``last_substep``.

Runs the synthetic cases of :mod:`motionphysics.optimize.sysid` (a ball thrown at the
ground, reference simulated with known parameters, fit started a factor 5 away) with
both gradient modes and prints a markdown table for BENCHMARKS.md ("System
identification") plus the raw results as JSON.

    .venv/bin/python benchmarks/bench_sysid.py [--size fast|full] [--cases elastic,metal]
        [--modes full,last_substep] [--iters N] [--json out.json]

``--recovery`` runs the physical-value table instead (issue 11): the
:data:`~motionphysics.optimize.sysid.RECOVERIES` (non-spherical drops on a frictional
or sticky floor; E, mu, tau_Y) through ``run_fit`` (global + gradient stage) from 10x
off and from the top and the bottom of the range, with the time each fit took:

    .venv/bin/python benchmarks/bench_sysid.py --recovery [--size tiny|full]
        [--cases elastic_cube_frictional,...] [--no-global] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile


def _fmt(v: float) -> str:
    a = abs(v)
    return f"{v:.4g}" if (a == 0 or 1e-3 <= a < 1e5) else f"{v:.3e}"


def main(argv: list[str] | None = None) -> int:
    from motionphysics.optimize.sysid import CASES, run_case
    from motionphysics.runtime import set_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=["fast", "full", "tiny"], default=None)
    ap.add_argument("--cases", default=None)
    ap.add_argument("--recovery", action="store_true", help="the physical-value table")
    ap.add_argument("--no-global", action="store_true", help="--recovery: gradient stage only")
    ap.add_argument("--modes", default="full,last_substep")
    ap.add_argument("--iters", type=int, default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    set_threads()
    if args.recovery:
        return _recovery(args)
    args.size = args.size or "fast"
    rows = []
    for name in (args.cases or ",".join(CASES)).split(","):
        for mode in args.modes.split(","):
            with tempfile.TemporaryDirectory() as d:
                r = run_case(name, d, size=args.size, grad_mode=mode, iterations=args.iters)
            rows.append(r)
            print(json.dumps(r), file=sys.stderr, flush=True)
    print(
        "| case | grad_mode | param | true (sim) | start (sim) | recovered (sim) | error | tol "
        "| iters to tol | iters | s/iter |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        for n, e in r["errors"].items():
            err = f"{100 * e['error']:.1f} %" if e["kind"] == "rel" else f"{e['error']:.3f}"
            tol = f"{100 * e['tolerance']:.0f} %" if e["kind"] == "rel" else f"{e['tolerance']}"
            print(
                f"| {r['case']} | {r['grad_mode']} | {n} | {_fmt(r['true_sim'][n])} | "
                f"{_fmt(r['start_sim'][n])} | {_fmt(float(r['final_sim'][n]))} | {err} | {tol} | "
                f"{r['iterations_to_tolerance'] if r['iterations_to_tolerance'] is not None else '-'} | "
                f"{r['iterations']} | {r['seconds_per_iteration']:.2f} |"
            )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


def _recovery(args) -> int:
    from motionphysics.optimize.sysid import RECOVERIES, run_recovery

    rows = []
    for name in (args.cases or ",".join(RECOVERIES)).split(","):
        with tempfile.TemporaryDirectory() as d:
            for r in run_recovery(
                name, d, size=args.size or "full", global_search=not args.no_global
            ):
                rows.append(r)
                print(json.dumps(r), file=sys.stderr, flush=True)
    print(
        "| case | param | true | start | fitted | error | ok | global cand. | iters | "
        "fit s | particles | substeps |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        g = r["global"]["candidates"] if r["global"] else "-"
        print(
            f"| {r['case']} | {r['param']} | {_fmt(r['true'])} | {r['start']} "
            f"{_fmt(r['start_value'])} | {_fmt(r['fitted'])} | {100 * r['error']:.1f} % | "
            f"{'yes' if r['ok'] else 'NO'} | {g} | {r['iterations']} | {r['seconds']:.0f} | "
            f"{r['particles']} | {r['substeps']} |"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
