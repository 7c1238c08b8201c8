"""Does a prior move the parameters the way the words say? (issue 13's direction bar)

For each scene and seed, two ``motionphysics run CONFIG --prior PRIOR --loss lmd`` runs
start from the same material and differ only in the prompt: "stiff, bounces high" against
"soft, wobbly, squashes" (class elastic, E optimised), and "thin runny water splashes"
against "thick honey oozes slowly" (class newtonian, mu optimised). The result is read
from each run's ``params.json``, as a user would read it. The bar: the stiff prompt's E at
least 3x the soft prompt's, the thin prompt's mu at least 10x below the thick prompt's; a third pair (plasticine,
yield stress: "keeps its shape" against "squashes flat and stays flat", bar 3) with
``--classes plasticine``. ``--prior`` picks the prior (default ``motion``, the embedded
motion prior; ``cogvideox`` / ``modelscope`` with ``--prior-path``, a local model; the
embedded pixel prior ``tiny`` was removed on 2026-12-03).

``--invariance`` instead runs one prompt on one shape in three textures and two geometry
variants, with ``lmd`` and with ``sds``, and reports the spread (standard deviation) of
the optimised log10 E of each loss (the paper's Figure 3 claim: smaller with lmd).

    python benchmarks/bench_prior_direction.py --iters 20 --seeds 3 --out /tmp/direction
    python benchmarks/bench_prior_direction.py --invariance --iters 20 --out /tmp/inv

The starts are where the parameter changes what is seen at the scenes' 0.3 m size (E
1e5 Pa: stiffer looks rigid; mu 1 Pa s: between a splash and an ooze); the tiny prior's
figures in BENCHMARKS.md (removed since) started from E 3e8 and mu 0.1. The scenes are not in the
priors' training data: the real capture in
``../shared/data/real/donut.ply`` (when present) and a capsule mesh written here.
``--loss-options`` passes options to the loss (JSON), e.g.
``'{"form": "classifier_score", "guidance": 5}'``; ``--contrast`` sets each run's
``negative_prompt`` to the other prompt of its pair (the pairwise contrast).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real" / "donut.ply"
BUILTIN = ("duck", "sphere", "bird", "cube")
"""Builtin scenes ``--scenes`` also takes: shapes the direction bar was not measured on."""
NOUN = {
    "donut": "ring",
    "capsule": "capsule",
    "duck": "duck",
    "sphere": "ball",
    "bird": "bird",
    "cube": "cube",
}

PAIRS = {
    "elastic": {
        "param": "E",
        "start": {"class": "elastic", "density": 1100, "E": 1.0e5, "nu": 0.3},
        "up": "A stiff {obj} is dropped, stays rigid and bounces high off the ground",
        "down": "A soft, wobbly {obj} is dropped, squashes and wobbles like jelly",
        "bar": 3.0,
    },
    "newtonian": {
        "param": "mu",
        "start": {"class": "newtonian", "density": 1000, "mu": 1.0, "kappa": 2.2e9},
        "up": "Thick honey shaped like a {obj} oozes slowly over the ground",
        "down": "Thin runny water shaped like a {obj} splashes and spreads thin",
        "bar": 10.0,
    },
    "plasticine": {
        "param": "tau_Y",
        "start": {"class": "plasticine", "density": 1500, "E": 2.0e6, "nu": 0.3, "tau_Y": 2.0e4},
        "up": "A hard clay {obj} is dropped and keeps its shape when it lands",
        "down": "A soft clay {obj} is dropped, squashes flat and stays squashed",
        "bar": 3.0,
    },
    "sand": {
        "param": "theta_fric",
        "start": {"class": "sand", "density": 1600, "theta_fric": 35.0},
        "up": "A {obj} of coarse, rough gravel is dropped and stays a tall, steep heap",
        "down": "A {obj} of fine, dry sand is dropped, collapses and spreads out flat",
        "bar": 1.3,  # the friction angle's whole range is 20-50 degrees (2.5x)
    },
    "non_newtonian": {
        "param": "tau_Y",
        "start": {
            "class": "non_newtonian",
            "density": 1200,
            "mu": 1.0,
            "kappa": 2.0e9,
            "tau_Y": 100.0,
            "eta": 0.5,
            "n": 0.6,
        },
        "up": "A {obj} of thick toothpaste is dropped and holds its shape like a stiff paste",
        "down": "A {obj} of runny paint is dropped, flows and spreads out thin",
        "bar": 3.0,
    },
    "foam": {
        "param": "E",
        "start": {
            "class": "foam",
            "density": 100,
            # E / rho = 50 m^2/s^2: the foam deforms visibly when it lands (at 3e4 Pa it
            # barely deformed, max shape change 1 %, and bounced: nothing to squash)
            "E": 5.0e3,
            "nu": 0.2,
            "tau_Y": 1.0e5,
            "eta": 0.5,
        },
        "up": "A firm foam {obj} is dropped and keeps its shape when it lands",
        "down": "A soft, squishy foam {obj} is dropped and squashes flat",
        "bar": 3.0,
    },
    "metal": {
        "param": "tau_Y",
        "start": {"class": "metal", "density": 7800, "E": 2.0e11, "nu": 0.3, "tau_Y": 2.0e7},
        "up": "A hard steel {obj} hits the ground and keeps its shape, not a dent",
        "down": "A soft lead {obj} hits the ground, dents and squashes flat",
        "bar": 3.0,
    },
}


def _mesh(dirpath: Path) -> Path:
    import trimesh

    path = dirpath / "capsule.obj"
    if not path.exists():
        trimesh.creation.capsule(height=1.0, radius=0.35, count=[24, 24]).export(path)
    return path


def _scenes(tmp: Path, which: list[str]) -> dict[str, dict]:
    out = {}
    if "real" in which:
        if not REAL.is_file():
            raise SystemExit(f"{REAL}: the real capture is not there (pass --scenes mesh)")
        out["donut (real 3DGS)"] = {
            "source": str(REAL),
            "scale": 0.3,
            "translate": [0, 0, 0.3],
            "max_particles": 1500,
        }
    for name in BUILTIN:
        if name in which:  # scenes the prior was never tuned on (other shapes, same start)
            out[f"{name} (builtin)"] = {
                "source": f"builtin:{name}",
                "scale": 0.3,
                "translate": [0, 0, 0.3],
                "max_particles": 1500,
            }
    if "mesh" in which:
        out["capsule (mesh)"] = {
            "source": str(_mesh(tmp)),
            "scale": 0.3,
            "rotate": [["x", 70]],
            "translate": [0, 0, 0.3],
            "max_particles": 1500,
        }
    return out


def _config(
    scene: dict,
    pair: dict,
    prompt: str,
    loss: dict,
    iters: int,
    seed: int,
    prior: str = "motion",
    all_params: bool = False,
) -> dict:
    cfg = {
        "scene": scene,
        "prompt": prompt,
        "material": dict(pair["start"]),
        "sim": {"grid": 24, "frames": 16, "frame_dt": 0.05, "substeps": "auto"},
        "boundary_conditions": [
            {
                "type": "surface_collider",
                "point": [0, 0, 0],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": 0.5,
            },
            {"type": "bounding_box"},
        ],
        "camera": {"azimuth": 30, "elevation": 15, "width": 96, "height": 96},
        "optimize": {
            "prior": prior,
            "losses": [loss],
            "iterations": iters,
            "seed": seed,
            "params": [pair["param"]],
        },
    }
    if all_params:  # as a user who names none: every parameter of the class is refined
        del cfg["optimize"]["params"]
    return cfg


def _run(cfg: dict, out: Path, prior_path: str | None) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    if prior_path:
        cfg["optimize"]["prior_path"] = prior_path
    path = out / "config.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    exe = Path(sys.executable).with_name("motionphysics")
    cmd = [str(exe), "run", str(path), "--out", str(out / "run"), "--force", "--quiet"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr[-800:]}")
    p = json.loads((out / "run" / "params.json").read_text())
    losses = [h.get("loss") for h in p.get("history", [])]
    return {"params": p["params"], "seconds": time.perf_counter() - t0, "losses": losses}


def direction(args, tmp: Path) -> dict:
    scenes = _scenes(tmp, args.scenes)
    jobs = []
    for sname, scene in scenes.items():
        for cls in args.classes:
            pair = PAIRS[cls]
            obj = NOUN[sname.split()[0]]
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                for side in ("up", "down"):
                    other = "down" if side == "up" else "up"
                    loss = {"type": args.loss, **args.loss_options}
                    if args.contrast:
                        loss["negative_prompt"] = pair[other].format(obj=obj)
                    cfg = _config(
                        scene,
                        pair,
                        pair[side].format(obj=obj),
                        loss,
                        args.iters,
                        seed,
                        args.prior,
                        args.all_params,
                    )
                    key = (sname, cls, seed, side)
                    jobs.append((key, cfg, args.out / f"{len(jobs):03d}"))
    with ThreadPoolExecutor(args.workers) as pool:
        futs = {key: pool.submit(_run, cfg, out, args.prior_path) for key, cfg, out in jobs}
        results = {key: f.result() for key, f in futs.items()}
    rows = []
    for sname in scenes:
        for cls in args.classes:
            pair = PAIRS[cls]
            name = pair["param"]
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                up = results[(sname, cls, seed, "up")]
                down = results[(sname, cls, seed, "down")]
                ratio = up["params"][name] / down["params"][name]
                rows.append(
                    {
                        "scene": sname,
                        "class": cls,
                        "param": name,
                        "seed": seed,
                        "start": pair["start"][name],
                        "up_end": up["params"][name],
                        "down_end": down["params"][name],
                        "ratio": ratio,
                        "bar": pair["bar"],
                        "pass": ratio >= pair["bar"],
                        "up_moved_up": up["params"][name] > pair["start"][name],
                        "down_moved_down": down["params"][name] < pair["start"][name],
                        "up_losses": up["losses"],
                        "down_losses": down["losses"],
                        "seconds": up["seconds"] + down["seconds"],
                    }
                )
    return {"rows": rows}


def invariance(args, tmp: Path) -> dict:
    variants = ["bird", "bird_textured", "bird_plain", "bird_red", "bird_simple"]
    pair = PAIRS["elastic"]
    jobs = []
    for loss_type in ("lmd", "sds"):
        for v in variants:
            scene = {
                "source": f"builtin:{v}",
                "scale": 0.3,
                "translate": [0, 0, 0.3],
                "max_particles": 1500,
            }
            loss = {"type": loss_type, **args.loss_options}
            cfg = _config(
                scene, pair, pair["up"].format(obj="bird"), loss, args.iters, 0, args.prior
            )
            jobs.append(((loss_type, v), cfg, args.out / f"inv-{loss_type}-{v}"))
    with ThreadPoolExecutor(args.workers) as pool:
        futs = {key: pool.submit(_run, cfg, out, args.prior_path) for key, cfg, out in jobs}
        results = {key: f.result() for key, f in futs.items()}
    table = {}
    for loss_type in ("lmd", "sds"):
        logs = [math.log10(results[(loss_type, v)]["params"]["E"]) for v in variants]
        mean = sum(logs) / len(logs)
        sd = math.sqrt(sum((x - mean) ** 2 for x in logs) / (len(logs) - 1))
        table[loss_type] = {"log10_E": dict(zip(variants, logs, strict=True)), "std": sd}
    return {"invariance": table, "lmd_smaller": table["lmd"]["std"] < table["sds"]["std"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=20)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. + seeds - 1")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--scenes", nargs="+", default=["real", "mesh"], choices=["real", "mesh", *BUILTIN]
    )
    ap.add_argument("--classes", nargs="+", default=["elastic", "newtonian"], choices=list(PAIRS))
    ap.add_argument("--loss", default="lmd", choices=["lmd", "sds"])
    ap.add_argument("--loss-options", type=json.loads, default={})
    ap.add_argument("--contrast", action="store_true", help="negative_prompt = the other prompt")
    ap.add_argument("--prior", default="motion", choices=["motion", "cogvideox", "modelscope"])
    ap.add_argument("--prior-path", default=None, help="a prior checkpoint (default: shipped)")
    ap.add_argument(
        "--all-params",
        action="store_true",
        help="leave optimize.params out: refine every parameter of the class (a user's default)",
    )
    ap.add_argument("--invariance", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    if args.prior != "motion" and not args.prior_path:
        ap.error(f"--prior {args.prior} needs --prior-path (a local model directory)")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        args.out = args.out or tmp / "runs"
        res = invariance(args, tmp) if args.invariance else direction(args, tmp)
    res["command"] = " ".join(sys.argv)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
