"""The gallery: one GIF per example config, from a real `motionphysics run` of it.

    .venv/bin/python docs/gallery/make_gallery.py NAME [NAME ...] [--work DIR]

NAME is an example's file name without `.yaml` (`jelly_cube`, `objects/axe_and_duck`).
Each example runs through `motionphysics run` (the material from the prompt unless the
file gives one: what a user gets), at a reduced size so one GIF costs about two minutes
of CPU: at most GALLERY_GRID cells, GALLERY_PARTICLES particles and a GALLERY_SIZE-pixel
video; frames, frame spacing, scene, forces and ground are the file's own. Runs are
sequential (one at a time: they share the machine with other work).

Writes `docs/gallery/NAME.gif` (the run's video.mp4, every frame at its frame spacing)
and one record per example in `docs/gallery/gallery.json`: the overrides used, the
config's sha256, the material the run chose, the wall time, and the motion measured
on the trajectory with the motion prior's own rules (`priors.motion_data.clip_measures`
and `group_of`, the rules that caption its training clips), so the record says which of
the eight motion groups the simulated motion falls in. `--work` keeps the run folders
(default: a temporary folder) and a PNG strip of eight frames per run, for looking.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
GALLERY = ROOT / "docs" / "gallery"
RECORD = GALLERY / "gallery.json"

GALLERY_GRID = 32
GALLERY_PARTICLES = 3000
GALLERY_SIZE = 160


def reduced(cfg: dict) -> tuple[dict, dict]:
    """The config at gallery size, and the overrides applied (only the reductions)."""
    cfg = json.loads(json.dumps(cfg))
    over: dict = {}
    sim = cfg.setdefault("sim", {})
    if int(sim.get("grid", 64)) > GALLERY_GRID:
        over["sim.grid"] = sim["grid"] = GALLERY_GRID
    parts = [cfg["scene"]] if "scene" in cfg else list(cfg.get("objects", []))
    total = sum(int(p.get("max_particles", 20000)) for p in parts)
    if total > GALLERY_PARTICLES:
        for p in parts:
            share = int(p.get("max_particles", 20000)) * GALLERY_PARTICLES // total
            over[f"max_particles[{p.get('name', 'scene')}]"] = p["max_particles"] = share
    cam = cfg.setdefault("camera", {})
    w, h = int(cam.get("width", 320)), int(cam.get("height", 256))
    if max(w, h) > GALLERY_SIZE:
        k = GALLERY_SIZE / max(w, h)
        cam["width"], cam["height"] = int(round(w * k / 8) * 8), int(round(h * k / 8) * 8)
        over["camera"] = [cam["width"], cam["height"]]
    return cfg, over


def gif(video: Path, out: Path, frame_dt: float) -> int:
    """``video`` as an optimised GIF at its own frame spacing; returns the frame count."""
    import imageio.v3 as iio
    from PIL import Image

    frames = [Image.fromarray(f) for f in iio.imread(video)]
    pal = [f.convert("P", palette=Image.Palette.ADAPTIVE, colors=128) for f in frames]
    pal[0].save(
        out,
        save_all=True,
        append_images=pal[1:],
        duration=int(round(frame_dt * 1000)),
        loop=0,
        optimize=True,
    )
    return len(frames)


def strip(video: Path, out: Path, n: int = 8) -> None:
    """``n`` evenly spaced frames side by side (for looking at the motion)."""
    import imageio.v3 as iio
    from PIL import Image

    frames = list(iio.imread(video))
    idx = np.linspace(0, len(frames) - 1, n).round().astype(int)
    Image.fromarray(np.concatenate([frames[i] for i in idx], axis=1)).save(out)


def measure(run: Path) -> dict:
    """Class, parameters and the motion group of a finished run directory."""
    from motionphysics.priors.motion_data import clip_measures, group_of

    params = json.loads((run / "params.json").read_text())
    with np.load(run / "trajectory.npz") as z:
        x, v, t = z["x"], z["v"], z["t"]
    rec = {"wall_s": round(float(params["wall_time_s"]), 1)}
    if params.get("objects"):
        rec["class"] = {o["name"]: o["class"] for o in params["objects"]}
        return rec
    m = clip_measures(x, v, t)
    rec.update(
        {
            "class": params["class"],
            "source": params["provenance"].get("backend"),
            "params": {k: float(f"{v:.4g}") for k, v in params["params"].items()},
            "substeps": (params.get("sim_context") or {}).get("substeps"),
            "measured_group": group_of(m, params["class"]),
            "measures": {k: round(float(v), 4) for k, v in m.items()},
        }
    )
    return rec


def make(name: str, work: Path) -> dict:
    src = EXAMPLES / f"{name}.yaml"
    text = src.read_text(encoding="utf-8")
    cfg, over = reduced(yaml.safe_load(text))
    cfg_path = work / f"{name.replace('/', '_')}.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    run = work / name.replace("/", "_")
    t0 = time.time()
    proc = subprocess.run(
        [sys.executable, "-m", "motionphysics", "--quiet", "run", str(cfg_path),
         "--out", str(run), "--force"],
        capture_output=True, text=True,
    )  # fmt: skip
    if proc.returncode != 0:
        raise SystemExit(f"{name}: motionphysics run failed\n{proc.stderr[-3000:]}")
    out = GALLERY / f"{Path(name).name}.gif"
    frame_dt = float(cfg.get("sim", {}).get("frame_dt", 0.04))
    n = gif(run / "video.mp4", out, frame_dt)
    strip(run / "video.mp4", work / f"{name.replace('/', '_')}_strip.png")
    rec = {
        "config": f"examples/{name}.yaml",
        "config_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "overrides": over,
        "frames": n,
        "command_s": round(time.time() - t0, 1),
        **measure(run),
    }
    if proc.stderr.strip():
        rec["stderr"] = proc.stderr.strip().splitlines()[-3:]
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="+", help="example names (file names without .yaml)")
    ap.add_argument("--work", type=Path, help="keep the runs and PNG strips here")
    args = ap.parse_args(argv)
    record = json.loads(RECORD.read_text()) if RECORD.is_file() else {}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in args.names:
            rec = make(name, work)
            record[name] = rec
            RECORD.write_text(json.dumps(dict(sorted(record.items())), indent=1) + "\n")
            print(
                f"{name}: {rec.get('class')} {rec.get('measured_group')} "
                f"{rec['command_s']} s -> docs/gallery/{Path(name).name}.gif",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
