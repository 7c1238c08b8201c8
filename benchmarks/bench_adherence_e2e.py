"""What you describe is what you simulate, end to end: motion adherence before and after
refinement with the embedded motion prior (issue 24's end-to-end bar).

For every motion group, a held-out prompt (``language.captions.group_prompt``: phrasings
the prior never saw, no material noun, so the kb reads the material from the motion
words) on three scenes: the real 3DGS capture ``../shared/data/real/donut.ply``, a capsule
mesh and ``builtin:duck``. Each scene/prompt runs twice through the command line, as a
user would:

1. ``motionphysics run CONFIG`` with kb initialisation and no refinement;
2. ``motionphysics run CONFIG --prior motion --loss lmd --iters N`` (the same config,
   the kb's material as the start, ``optimize.seed`` = the seed);

and ``motionphysics eval RUN`` scores each against its prompt (``metrics.json``,
``motion_adherence.score``). With ``--seeds 2`` or more the refinement is repeated with other
seeds: the spread of their scores is the run-to-run noise a loss is judged against.

    python benchmarks/bench_adherence_e2e.py --iters 8 --seeds 2 --workers 1 --out DIR

``--size M`` scales every object so that its longest side is M metres (default: scale 0.3
for each source, which makes the donut capture a 6 cm ring, 1.5-2.5 cells at grid 16-24:
unresolved); each row reports ``cells``, the object's longest side over the grid spacing
at frame 0 (under 4 its deformation is the grid's, not the material's).

Prints JSON: one row per scene/prompt (group, prompt, kb class, start and end
parameters, adherence before and after per seed, change, noise) and the means.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_prior_direction import REAL, _mesh  # noqa: E402
from motionphysics.language.captions import GROUPS, group_prompt  # noqa: E402

SCENES = ("real", "mesh", "builtin")


def _scale(source: str, size: float | None) -> float:
    """The scene scale that makes ``source``'s longest side ``size`` metres (0.3 when
    ``size`` is None: the scale these benchmarks always used, whatever the source's size)."""
    if size is None:
        return 0.3
    import numpy as np

    from motionphysics.scene import load_scene

    means = load_scene(source).means.double().numpy()
    return float(size) / float(np.ptp(means, axis=0).max())


def _scenes(
    tmp: Path, which: list[str], particles: int, size: float | None = None
) -> dict[str, tuple[dict, str]]:
    """name -> (scene block, shape used for the prompt's noun)."""
    out: dict[str, tuple[dict, str]] = {}
    if "real" in which:
        if not REAL.is_file():
            raise SystemExit(f"{REAL}: the real capture is not there (leave out 'real')")
        block = {"source": str(REAL), "scale": _scale(str(REAL), size), "translate": [0, 0, 0.3]}
        out["donut (real 3DGS)"] = ({**block, "max_particles": particles}, "torus")
    if "mesh" in which:
        src = str(_mesh(tmp))
        block = {"source": src, "scale": _scale(src, size), "rotate": [["x", 70]]}
        out["capsule (mesh)"] = (
            {**block, "translate": [0, 0, 0.3], "max_particles": particles},
            "rod",
        )
    if "builtin" in which:
        src = "builtin:duck"
        block = {"source": src, "scale": _scale(src, size), "translate": [0, 0, 0.3]}
        out["duck (builtin)"] = ({**block, "max_particles": particles}, "duck")
    return out


def _cells(run: Path) -> float | None:
    """The object's longest side at frame 0 over the grid spacing."""
    try:
        import numpy as np

        x0 = np.load(run / "trajectory.npz")["x"][0]
        dx = json.loads((run / "params.json").read_text())["sim_context"]["dx"]
        return float(np.ptp(x0, axis=0).max()) / float(dx)
    except (OSError, KeyError, ValueError):
        return None


def _config(scene: dict, prompt: str, grid: int, frames: int) -> dict:
    # No material block: the kb reads the prompt. No boundary_conditions: the default
    # frictional floor at z = 0 (what a user gets).
    return {
        "scene": scene,
        "prompt": prompt,
        "sim": {"grid": grid, "frames": frames, "frame_dt": 0.05, "substeps": "auto"},
        "camera": {"azimuth": 30, "elevation": 15, "width": 96, "height": 96},
    }


def _cli(args: list[str]) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("motionphysics")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = subprocess.run([str(exe), *args], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(
            f"motionphysics {' '.join(args)} failed ({r.returncode}): {r.stderr[-800:]}"
        )
    return r


def _done(out: Path, text: str, extra: list[str]) -> bool:
    """A complete, evaluated run of the same config and flags is already in ``out``."""
    try:
        same = (out / "config.yaml").read_text() == text
        same = same and (out / "flags.json").read_text() == json.dumps(extra)
        p = json.loads((out / "run" / "params.json").read_text())
        return same and p.get("status") == "complete" and (out / "run" / "metrics.json").is_file()
    except (OSError, ValueError):
        return False


def _run(cfg: dict, out: Path, extra: list[str], reuse: bool = False) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "config.yaml"
    text = yaml.safe_dump(cfg, sort_keys=False)
    t0 = time.perf_counter()
    if not (reuse and _done(out, text, extra)):
        path.write_text(text)
        (out / "flags.json").write_text(json.dumps(extra))
        _cli(["run", str(path), "--out", str(out / "run"), "--force", "--quiet", *extra])
        _cli(["eval", str(out / "run"), "--quiet"])
    p = json.loads((out / "run" / "params.json").read_text())
    m = json.loads((out / "run" / "metrics.json").read_text())
    adh = m.get("motion_adherence") or {}
    motion = (p.get("optimise") or {}).get("motion") or {}
    return {
        "class": p.get("class"),
        "params": p["params"],
        "score": adh.get("score"),
        "explanations": adh.get("explanations"),
        "motion": motion,
        "cells": _cells(out / "run"),
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=8)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--groups", nargs="+", default=list(GROUPS), choices=GROUPS)
    ap.add_argument("--phrasing", type=int, default=0, help="which held-out phrasing (0 or 1)")
    ap.add_argument("--particles", type=int, default=1500, help="scene.max_particles")
    ap.add_argument("--grid", type=int, default=24, help="sim.grid")
    ap.add_argument("--frames", type=int, default=16, help="sim.frames (0.05 s apart)")
    ap.add_argument(
        "--size",
        type=float,
        default=None,
        help="longest side of every object [m] (default: scale 0.3)",
    )
    ap.add_argument(
        "--loss-options",
        type=json.loads,
        default=None,
        help='options of the lmd loss (JSON), e.g. \'{"negative_prompt": ""}\': the refined '
        "runs set optimize.losses to [{type: lmd, ...}] instead of passing --loss lmd",
    )
    ap.add_argument(
        "--prior-path", default=None, help="motion prior weights (default: the shipped ones)"
    )
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--reuse", action="store_true", help="keep complete runs of the same config in --out"
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        out = args.out or tmp / "runs"
        out.mkdir(parents=True, exist_ok=True)
        # the mesh beside the runs: its path is in every config, so --reuse finds them again
        scenes = _scenes(out, args.scenes, args.particles, args.size)
        jobs = []
        for sname, (scene, shape) in scenes.items():
            for g in args.groups:
                prompt = group_prompt(g, shape, args.phrasing)
                cfg = _config(scene, prompt, args.grid, args.frames)
                tag = f"{sname.split()[0]}-{g}"
                jobs.append(((sname, g, "kb"), cfg, out / f"{tag}-kb", []))
                for seed in range(args.seeds):
                    c = json.loads(json.dumps(cfg))
                    c["optimize"] = {"seed": seed}
                    extra = ["--prior", "motion", "--iters", str(args.iters)]
                    if args.prior_path:
                        extra += ["--prior-path", str(Path(args.prior_path).resolve())]
                    if args.loss_options is None:
                        extra[2:2] = ["--loss", "lmd"]
                    else:
                        c["optimize"]["losses"] = [{"type": "lmd", **args.loss_options}]
                    jobs.append(((sname, g, seed), c, out / f"{tag}-s{seed}", extra))
        with ThreadPoolExecutor(args.workers) as pool:
            futs = {
                key: pool.submit(_run, cfg, o, extra, args.reuse) for key, cfg, o, extra in jobs
            }
            res = {}
            for key, f in futs.items():
                try:
                    res[key] = f.result()
                except RuntimeError as e:  # a failed run is a row with its error, not a crash
                    res[key] = {"error": str(e)}
    rows = []
    for sname, (_, shape) in scenes.items():
        for g in args.groups:
            kb = res[(sname, g, "kb")]
            refined = [res[(sname, g, s)] for s in range(args.seeds)]
            after = [r.get("score") for r in refined if r.get("score") is not None]
            before = kb.get("score")
            row = {
                "scene": sname,
                "group": g,
                "prompt": group_prompt(g, shape, args.phrasing),
                "class": kb.get("class"),
                "cells": kb.get("cells"),
                "start": kb.get("params"),
                "ends": [r.get("params") for r in refined],
                "before": before,
                "after": after,
                "after_mean": statistics.mean(after) if after else None,
                "change": (statistics.mean(after) - before)
                if after and before is not None
                else None,
                "noise": (max(after) - min(after)) if len(after) > 1 else None,
                "motion_after": [r.get("motion", {}).get("after") for r in refined],
                "errors": [r["error"] for r in (kb, *refined) if "error" in r],
                "seconds": sum(r.get("seconds", 0.0) for r in (kb, *refined)),
            }
            rows.append(row)
    ok = [r for r in rows if r["change"] is not None]
    noise = [r["noise"] for r in rows if r["noise"] is not None]
    summary = {
        "mean_before": statistics.mean(r["before"] for r in ok) if ok else None,
        "mean_after": statistics.mean(r["after_mean"] for r in ok) if ok else None,
        "rose": sum(r["change"] > 0 for r in ok),
        "fell": sum(r["change"] < 0 for r in ok),
        "noise_max": max(noise) if noise else None,
        "worst_loss": min((r["change"] for r in ok), default=None),
    }
    if summary["noise_max"] is not None and summary["worst_loss"] is not None:
        summary["no_loss_beyond_noise"] = -summary["worst_loss"] <= summary["noise_max"]
    print(json.dumps({"rows": rows, "summary": summary, "command": " ".join(sys.argv)}, indent=1))


if __name__ == "__main__":
    main()
