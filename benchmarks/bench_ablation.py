"""The paper's ablations on our scenes: initialisation and loss, scored by every metric.

Rows: scene x method, where method is one of

- ``kb``     material from the prompt by the offline knowledge base, no optimisation;
- ``naive``  PhysFlow-style unconstrained estimate (an LLM asked without ranges);
- ``median`` every parameter at the median of its range (kb's class);
- ``lmd`` / ``sds`` / ``flow``  kb init, then optimisation against a video prior with
  that loss (``--prior motion|cogvideox|modelscope [--prior-path DIR]``).

Each row is a real ``motionphysics run`` of the example config with its ``material:``
block removed (so the init backend decides the material), then ``motionphysics eval``;
a row that cannot run here (no LLM endpoint, no prior, a prior or optimiser missing
from this build) is listed with the one-line reason instead of numbers.

    .venv/bin/python benchmarks/bench_ablation.py [--size small|full]
        [--scenes elastic_ball,sand_column] [--methods kb,naive,median,lmd,sds,flow]
        [--prior motion|cogvideox|modelscope [--prior-path DIR]] [--iters N] [--md out.md]
        [--keep DIR]
        [--clip DIR] [--viclip PTH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = (
    "elastic_ball",
    "metal_rod",
    "sand_column",
    "newtonian_droplet",
    "non_newtonian_toothpaste",
    "plasticine_blob",
)
INIT_METHODS = ("kb", "naive", "median")
LOSS_METHODS = ("lmd", "sds", "flow")


def _fmt(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, str):
        return v
    a = abs(v)
    return "0" if v == 0 else (f"{v:.4g}" if 1e-3 <= a < 1e5 else f"{v:.3e}")


def _config(scene: str, size: str, out: Path) -> Path:
    import yaml

    d = yaml.safe_load((ROOT / "examples" / f"{scene}.yaml").read_text())
    d.pop("material", None)  # the init backend decides the material
    if size == "small":
        d["scene"]["max_particles"] = min(int(d["scene"].get("max_particles", 4000)), 1500)
        d["sim"]["grid"] = min(int(d["sim"]["grid"]), 32)
        d.setdefault("camera", {}).update({"width": 64, "height": 64})
    p = out / f"{scene}.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


def _run(cmd: list[str]) -> tuple[int, str, float]:
    env = dict(os.environ)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "motionphysics", "--quiet", *cmd],
        capture_output=True,
        text=True,
        env=env,
    )
    err = [ln for ln in proc.stderr.splitlines() if ln.startswith("motionphysics")]
    return (
        proc.returncode,
        (err[-1] if err else proc.stderr.strip()[-200:]),
        time.perf_counter() - t0,
    )


def run_row(scene: str, method: str, args, work: Path) -> dict:
    cfg = _config(scene, args.size, work)
    out = work / f"{scene}-{method}"
    cmd = ["run", str(cfg), "--out", str(out), "--force"]
    if method in INIT_METHODS:
        cmd += ["--init", method, "--prior", "none"]
    else:
        if args.prior is None:
            return {
                "scene": scene,
                "method": method,
                "missing": "no prior: pass --prior motion|cogvideox|modelscope",
            }
        cmd += ["--init", "kb", "--prior", args.prior, "--loss", method]
        if args.prior_path:
            cmd += ["--prior-path", args.prior_path]
        if args.iters:
            cmd += ["--iters", str(args.iters)]
    rc, err, wall = _run(cmd)
    if rc != 0:
        return {"scene": scene, "method": method, "missing": err or f"exit status {rc}"}
    ev = ["eval", str(out)]
    if args.clip:
        ev += ["--clip", args.clip]
    if args.viclip:
        ev += ["--viclip", args.viclip]
    rc, err, _ = _run(ev)
    if rc != 0:
        return {"scene": scene, "method": method, "missing": f"eval failed: {err}"}
    m = json.loads((out / "metrics.json").read_text())
    p = json.loads((out / "params.json").read_text())
    return {
        "scene": scene,
        "method": method,
        "class": p.get("class"),
        "params": {"density": p.get("density"), **(p.get("params") or {})},
        "oc": m.get("oc"),
        "clipsim": m.get("clipsim"),
        "ecms": m.get("ecms"),
        "ecms_terms": m.get("ecms_terms"),
        "adherence": (m.get("motion_adherence") or {}).get("score"),
        "optimisation_s": m.get("optimisation_time_s"),
        "wall_s": wall,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | method | class | parameters | OC ×10⁻² | CLIPSIM ×10⁻² | ECMS ↓ (motion / temporal / spatial) "
        "| motion adherence ↑ | optimisation [s] | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "missing" in r:
            lines.append(f"| {r['scene']} | {r['method']} | missing: {r['missing']} |||||||")
            continue
        params = ", ".join(f"{k}={_fmt(v)}" for k, v in r["params"].items())
        t = r["ecms_terms"] or {}
        ecms = f"{_fmt(r['ecms'])} ({_fmt(t.get('motion'))} / {_fmt(t.get('temporal'))} / {_fmt(t.get('spatial'))})"
        lines.append(
            f"| {r['scene']} | {r['method']} | {r['class']} | {params} | "
            f"{_fmt(None if r['oc'] is None else 100 * r['oc'])} | "
            f"{_fmt(None if r['clipsim'] is None else 100 * r['clipsim'])} | {ecms} | "
            f"{_fmt(r['adherence'])} | {_fmt(r['optimisation_s'])} | {r['wall_s']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=["small", "full"], default="small")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--methods", default=",".join(INIT_METHODS + LOSS_METHODS))
    ap.add_argument("--prior", choices=["motion", "cogvideox", "modelscope"], default=None)
    ap.add_argument("--prior-path", default=None)
    ap.add_argument("--iters", type=int, default=None)
    ap.add_argument("--clip", default=None)
    ap.add_argument("--viclip", default=None)
    ap.add_argument("--md", default=None, help="write the Markdown table here too")
    ap.add_argument("--json", default=None)
    ap.add_argument("--keep", default=None, help="keep the run directories in this folder")
    args = ap.parse_args(argv)
    methods = args.methods.split(",")
    for m in methods:
        if m not in INIT_METHODS + LOSS_METHODS:
            ap.error(f"--methods: unknown method {m!r}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for scene in args.scenes.split(","):
            for method in methods:
                r = run_row(scene, method, args, work)
                rows.append(r)
                print(json.dumps(r), file=sys.stderr, flush=True)
    text = markdown(rows)
    cmd = "python benchmarks/bench_ablation.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    text = f"Command: `{cmd.strip()}`\n\n" + text
    print(text)
    if args.md:
        Path(args.md).write_text(text)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
