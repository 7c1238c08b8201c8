"""Training clips for the embedded tiny prior: our simulator + renderer, random setups.

``motionphysics prior data OUT`` writes ``OUT/shard-XXXXX.npz`` files, each holding
``frames`` uint8 ``[N, T, H, W, 3]``, the measured motion ``measures`` (JSON list, one
dict per clip: rebound ratio, height / spread ratios, oscillation, flow speed; see
:func:`motion_measures`) and the drawn ``specs`` (JSON). Clip ``i`` of a data set with
seed ``S`` is fully determined by ``(S, i)`` (its own ``numpy`` generator), so the data
set is deterministic per seed whatever the number of workers, and a killed generation
resumes by skipping the shards already on disk (each shard is written atomically).

A clip is one forward simulation through the same code path as ``motionphysics
simulate`` (scene.prepare, pipeline material resolution and sim map, sim.build,
pipeline.render_view): a builtin shape or a random compound of ellipsoids / boxes,
recoloured (random hue, optional checker texture, per-splat noise), scaled, rotated,
dropped from a random height with a random initial velocity onto a frictional floor,
seen from a random orbit camera. Material: one of the 7 classes with every parameter
drawn across the class's handbook range (log-uniform where the catalogue says ``log``).

This module holds no physics and no rendering of its own, and no captions (see
:mod:`.captions`).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CLIP_FRAMES",
    "CLIP_SIZE",
    "HELD_OUT_SHAPES",
    "TRAIN_SHAPES",
    "MEASURE_PARTICLES",
    "ClipSpec",
    "draw_spec",
    "generate",
    "load_shards",
    "motion_measures",
    "render_clip",
    "subsample_trajectory",
]

CLIP_FRAMES = 16
"""Frames per clip (frame 0 = the drop's initial state)."""
CLIP_SIZE = 32
"""Pixel height and width of a clip."""
FRAME_DT = 0.05
"""Seconds between clip frames (16 frames: 0.75 s, enough for a 0.5 m drop and rebound)."""
SUBSTEPS = 50
"""Substeps per frame (dt = 1 ms); the sim map compresses stiffness to it."""
MAX_SUBSTEPS = 400
"""A draw whose mapped material needs more than SUBSTEPS for the CFL limit (stiff
plasticine, metal and foam: 20 % of draws) runs at its CFL count up to this cap instead
of being dropped (dropping them left the stiff classes under-represented)."""
GRID = 20
"""Cells along the longest side of the fitted domain."""
MAX_PARTICLES = 400
MAX_SPLATS = 1500
GROUND_SPLATS = 1600
SHARD_SIZE = 10

TRAIN_SHAPES = ("sphere", "cube", "column", "rod", "bird", "compound")
"""Shapes drawn for training clips (``compound``: random union of 2-3 primitives)."""
HELD_OUT_SHAPES = ("duck", "torus", "bird_simple")
"""Shapes never drawn for training clips: the held-out evaluation uses them."""

# Densities per class [kg/m^3], log-uniform (typical values; the handbook range of
# density is common to all classes and far wider than any one material's).
_DENSITY = {
    "elastic": (900.0, 1600.0),
    "plasticine": (1300.0, 2000.0),
    "metal": (2700.0, 8900.0),
    "foam": (30.0, 300.0),
    "sand": (1400.0, 1900.0),
    "newtonian": (800.0, 1400.0),
    "non_newtonian": (1000.0, 1500.0),
}


@dataclass(frozen=True)
class ClipSpec:
    """Everything that determines one clip (JSON-serialisable via ``to_dict``)."""

    index: int
    cls: str
    density: float
    params: dict[str, float]
    shape: str
    parts: list[dict[str, Any]] | None
    """``compound`` only: [{kind: ellipsoid|box, centre [3], size [3]}]."""
    hue: float
    checker: bool
    noise: float
    scale: float
    """Longest side of the object [m]."""
    rotate: list[tuple[str, float]]
    drop: float
    """Gap between the object's lowest point and the floor [m]."""
    velocity: tuple[float, float, float]
    friction: float
    azimuth: float
    elevation: float
    zoom: float
    """Orbit radius / the auto-framed radius."""

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["rotate"] = [list(r) for r in self.rotate]
        d["velocity"] = list(self.velocity)
        return d


def _draw_param(rng: np.random.Generator, ps) -> float:
    lo, hi = float(ps.low), float(ps.high)
    if getattr(ps, "default", None) is not None and rng.random() < 0.5:
        return float(ps.default)
    if ps.scale == "log" and lo > 0:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return float(rng.uniform(lo, hi))


def draw_spec(seed: int, index: int, shapes: tuple[str, ...] = TRAIN_SHAPES) -> ClipSpec:
    """The random setup of clip ``index`` of a data set with ``seed`` (deterministic)."""
    from motionphysics.config import MATERIAL_CLASSES
    from motionphysics.materials.catalog import MATERIALS

    rng = np.random.default_rng([int(seed), int(index)])
    cls = MATERIAL_CLASSES[int(rng.integers(len(MATERIAL_CLASSES)))]
    params = {p.name: _draw_param(rng, p) for p in MATERIALS[cls].params}
    lo, hi = _DENSITY[cls]
    density = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    shape = shapes[int(rng.integers(len(shapes)))]
    parts = None
    if shape == "compound":
        parts = []
        for _ in range(int(rng.integers(2, 4))):
            parts.append(
                {
                    "kind": "ellipsoid" if rng.random() < 0.6 else "box",
                    "centre": rng.uniform(-0.25, 0.25, 3).round(4).tolist(),
                    "size": rng.uniform(0.2, 0.6, 3).round(4).tolist(),
                }
            )
    rotate = [(ax, float(rng.uniform(-40, 40))) for ax in ("x", "y") if rng.random() < 0.6]
    if rng.random() < 0.7:
        rotate.append(("z", float(rng.uniform(0, 360))))
    return ClipSpec(
        index=int(index),
        cls=cls,
        density=density,
        params=params,
        shape=shape,
        parts=parts,
        hue=float(rng.random()),
        checker=bool(rng.random() < 0.4),
        noise=float(rng.uniform(0.0, 0.12)),
        scale=float(rng.uniform(0.22, 0.45)),
        rotate=rotate,
        drop=float(rng.uniform(0.05, 0.45)),
        velocity=(
            float(rng.normal(0, 0.35)),
            float(rng.normal(0, 0.35)),
            float(rng.uniform(-1.2, 0.4)),
        ),
        friction=float(rng.uniform(0.1, 0.9)),
        azimuth=float(rng.uniform(0, 360)),
        elevation=float(rng.uniform(3, 35)),
        zoom=float(rng.uniform(0.9, 1.35)),
    )


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    import colorsys

    return np.array(colorsys.hsv_to_rgb(h % 1.0, s, v))


def _build_scene(spec: ClipSpec, rng: np.random.Generator):
    """The recoloured Gaussian scene of ``spec`` (unit size, centred)."""
    import torch

    from motionphysics.scene import load_scene
    from motionphysics.scene.gaussians import SH_C0

    if spec.shape == "compound":
        import trimesh

        from motionphysics.scene import builtin as b

        parts = []
        for p in spec.parts or []:
            colour = b._solid((0.5, 0.5, 0.5))
            if p["kind"] == "ellipsoid":
                parts.append(b._ellipsoid(p["centre"], [0.5 * s for s in p["size"]], colour))
            else:
                m = trimesh.creation.box(extents=p["size"])
                m.apply_translation(p["centre"])
                parts.append(b._mesh_part(m, colour))
        scene = b._assemble(parts, count=2500, seed=spec.index).to(torch.float32)
    else:
        scene = load_scene(f"builtin:{spec.shape}")
    # Recolour: the shape's own pattern (luminance) modulates a random hue, so multi-part
    # builtins keep visible parts; a 3-D checker makes rotation visible.
    base = scene.base_colors().numpy().astype(np.float64)
    lum = base.mean(1, keepdims=True)
    lum = 0.55 + 0.45 * (lum - lum.mean()) / max(float(lum.std()), 1e-6) * 0.3
    rgb = _hsv(spec.hue, rng.uniform(0.45, 0.95), rng.uniform(0.55, 0.95))[None, :] * lum
    if spec.checker:
        p = scene.means.numpy()
        cell = 0.18
        parity = np.floor(p / cell).astype(np.int64).sum(1) % 2
        rgb = np.where(parity[:, None] == 0, rgb, rgb * 0.45)
    rgb = rgb + rng.normal(0, spec.noise, rgb.shape)
    rgb = np.clip(rgb, 0.02, 0.98)
    out = scene.clone()
    sh = out.sh.clone()
    sh[:, 0, :] = torch.as_tensor((rgb - 0.5) / SH_C0, dtype=sh.dtype)
    if sh.shape[1] > 1:
        sh[:, 1:, :] = sh[:, 1:, :] * 0.0 + torch.as_tensor(
            rng.normal(0, 0.05 * spec.noise, tuple(sh[:, 1:, :].shape)), dtype=sh.dtype
        )
    out.sh = sh
    if out.num > MAX_SPLATS:  # a 32 x 32 render needs far fewer splats; render cost
        n0 = out.num
        keep = np.sort(rng.choice(n0, MAX_SPLATS, replace=False))
        out = out.subset(torch.as_tensor(keep))
        out.log_scales = out.log_scales + 0.5 * float(np.log(n0 / MAX_SPLATS))  # no holes
    return out


def _config(spec: ClipSpec, z_lowest: float):
    from motionphysics.config import config_from_dict

    return config_from_dict(
        {
            "scene": {
                "source": f"builtin:{spec.shape}",
                "scale": spec.scale,
                "rotate": [list(r) for r in spec.rotate],
                "translate": [0.0, 0.0, spec.drop - z_lowest],
                "max_particles": MAX_PARTICLES,
            },
            "material": {"class": spec.cls, "density": spec.density, **spec.params},
            "sim": {
                "grid": GRID,
                "frames": CLIP_FRAMES,
                "frame_dt": FRAME_DT,
                "substeps": SUBSTEPS,
                "gravity": [0.0, 0.0, -9.8],
                "initial_velocity": list(spec.velocity),
            },
            "boundary_conditions": [
                {
                    "type": "surface_collider",
                    "point": [0, 0, 0],
                    "normal": [0, 0, 1],
                    "mode": "frictional",
                    "friction": spec.friction,
                },
                {"type": "bounding_box"},
            ],
            "camera": {
                "azimuth": spec.azimuth,
                "elevation": spec.elevation,
                "width": CLIP_SIZE,
                "height": CLIP_SIZE,
                "fov": 40.0,
            },
        },
        "<prior data>",
    )


class _Quiet:
    """The stage handle ``simulate_forward`` reports to (no display here)."""

    def note(self, *_a) -> None:
        pass

    def advance(self, *_a) -> None:
        pass


def render_clip(spec: ClipSpec) -> tuple[np.ndarray, dict[str, Any]]:
    """Simulate and render ``spec`` -> (frames uint8 [T, H, W, 3], trajectory dict).

    The trajectory holds ``x [T, P, 3]`` m, ``v [T, P, 3]``, ``t [T]``, ``mass [P]`` kg,
    ``gravity [3]`` and ``det_F [T, P]`` (what :func:`motion_measures` reads).
    """
    import torch

    from motionphysics.assembly import (
        ground_splats,
        render_view,
        resolve_camera,
        resolve_material,
        resolve_simulation,
        simulate_forward,
    )
    from motionphysics.errors import UserInputError
    from motionphysics.render.camera import camera_from_config
    from motionphysics.scene.prepare import prepare, transform_scene

    rng = np.random.default_rng([spec.index, 7])
    scene = _build_scene(spec, rng)
    probe = _config(spec, 0.0)
    placed, _ = transform_scene(scene, spec.scale, probe.scene.rotate, (0.0, 0.0, 0.0))
    z_lowest = float(placed.means[:, 2].min())
    cfg = _config(spec, z_lowest)
    sim_scene = prepare(scene, cfg.scene, cfg.sim, list(cfg.boundary_conditions))
    cfg, _ = resolve_camera(cfg, sim_scene)
    cam = cfg.camera.model_copy(update={"radius": float(cfg.camera.radius) * spec.zoom})
    cfg = cfg.model_copy(update={"camera": cam})
    camera = camera_from_config(cfg.camera)
    ground = ground_splats(cfg, sim_scene)
    if ground is not None and ground["means"].shape[0] > GROUND_SPLATS:
        # fewer, wider floor splats (same coverage): the floor is most of a 32 x 32 render's cost
        n0 = ground["means"].shape[0]
        sel = torch.as_tensor(np.sort(rng.choice(n0, GROUND_SPLATS, replace=False)))
        ground = {k: v[sel] for k, v in ground.items()}
        ground["covs"][:, :2, :2] *= n0 / GROUND_SPLATS
    material = resolve_material(cfg, None)["material"]
    try:
        sim_values = resolve_simulation(material, cfg, sim_scene).values
    except UserInputError as err:
        if "sim.substeps" not in str(err):
            raise
        # too stiff for SUBSTEPS: the CFL count (``auto``), when it is under the cap
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"substeps": "auto"})})
        res = resolve_simulation(material, cfg, sim_scene)
        if res.substeps > MAX_SUBSTEPS:
            raise UserInputError(
                f"{spec.cls} draw needs {res.substeps} substeps per frame (cap {MAX_SUBSTEPS})"
            ) from err
        sim_values = res.values
    xs, Fs, vs, _ = simulate_forward(
        sim_scene, cfg, material, sim_values, "cpu", CLIP_FRAMES, _Quiet()
    )
    bg = tuple(float(v) for v in cfg.camera.background)
    out = []
    with torch.no_grad():
        for i in range(xs.shape[0]):
            rgb = render_view(
                sim_scene, torch.from_numpy(xs[i]), torch.from_numpy(Fs[i]), camera, bg, ground
            )
            out.append((np.clip(rgb.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    vol = sim_scene.volumes.numpy() if hasattr(sim_scene.volumes, "numpy") else sim_scene.volumes
    traj = {
        "x": xs,
        "v": vs,
        "t": np.arange(CLIP_FRAMES) * FRAME_DT,
        "mass": np.asarray(vol, dtype=np.float64) * spec.density,
        "gravity": np.array([0.0, 0.0, -9.8]),
        "det_F": np.linalg.det(Fs.astype(np.float64)),
    }
    return np.stack(out), traj


MEASURE_PARTICLES = 256
"""Particles kept per clip (a fixed random subset) for the stored trajectory."""


def subsample_trajectory(traj: dict[str, np.ndarray], seed: int) -> dict[str, np.ndarray]:
    """The stored trajectory of a clip: ``x``, ``v`` float16 [T, 256, 3], ``t`` [T] (a random
    particle subset, so the measures can be recomputed from a shard)."""
    P = traj["x"].shape[1]
    k = min(MEASURE_PARTICLES, P)
    idx = np.sort(np.random.default_rng([seed, 3]).choice(P, k, replace=False))
    return {
        "x": np.asarray(traj["x"][:, idx], np.float16),
        "v": np.asarray(traj["v"][:, idx], np.float16),
        "t": np.asarray(traj["t"], np.float64),
    }


def _rigid_residual(a0: np.ndarray, b: np.ndarray) -> float:
    """Mean distance [m] of ``b`` [P, 3] from the best rigid (Kabsch) motion of ``a0``."""
    a = a0 - a0.mean(0)
    c = b - b.mean(0)
    u, _, vt = np.linalg.svd(c.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.linalg.norm(c - a @ r.T, axis=1).mean())


def motion_measures(traj: dict[str, np.ndarray]) -> dict[str, float]:
    """The measured motion of one clip (what the captions are written from).

    ``traj``: ``x [T, P, 3]`` m, ``v [T, P, 3]`` m/s, ``t [T]`` s (equal particle masses;
    z up). Keys: ``rebound`` (centroid rise after its lowest point / fall before it,
    metrics.physical's rebound ratio), ``final_height`` / ``min_height`` (vertical
    extent over the first frame's), ``spread`` / ``max_spread`` (horizontal spread over
    the first frame's), ``deform`` / ``max_deform`` (final / largest mean distance from
    the best rigid motion of frame 0, over the object size: rotation-invariant shape
    change), ``wobble`` (number of reversals of the deformation after the first contact
    with a swing over 0.008), ``late_speed`` (mean particle speed in the last quarter
    [m/s]) and ``fell`` (centroid drop over object size).
    """
    from motionphysics.metrics.physical import physical_metrics

    x = np.asarray(traj["x"], dtype=np.float64)
    v = np.asarray(traj["v"], dtype=np.float64)
    t = np.asarray(traj["t"], dtype=np.float64)
    m = physical_metrics({"x": x, "v": v, "t": t, "gravity": np.array([0.0, 0.0, -9.8])})
    T = x.shape[0]
    size = max(float(np.ptp(x[0], axis=0).max()), 1e-9)
    deform = np.array([_rigid_residual(x[0], x[i]) for i in range(T)]) / size
    # wobble: reversals of the deformation signal after it first exceeds 0.005
    wob = 0
    on = np.nonzero(deform > 0.005)[0]
    if on.size:
        seg = deform[on[0] :]
        last, direction = seg[0], 0
        for val in seg[1:]:
            if direction >= 0 and val < last - 0.008:
                wob += direction > 0
                direction, last = -1, val
            elif direction <= 0 and val > last + 0.008:
                wob += direction < 0
                direction, last = 1, val
            elif (direction >= 0 and val > last) or (direction <= 0 and val < last):
                last = val
    late = float(np.linalg.norm(v[-max(2, T // 4) :], axis=-1).mean())
    return {
        "rebound": float(m["rebound_ratio"]),
        "final_height": float(m["final_height_ratio"]),
        "min_height": float(m["min_height_ratio"]),
        "spread": float(m["spread_ratio"]),
        "max_spread": float(m["max_spread_ratio"]),
        "deform": float(deform[-1]),
        "max_deform": float(deform.max()),
        "wobble": float(wob),
        "late_speed": late,
        "fell": float(m["centroid_drop"]) / size,
    }


# ---- the data set ------------------------------------------------------------------


def _shard_path(out: Path, k: int) -> Path:
    return out / f"shard-{k:05d}.npz"


def _make_shard(args: tuple[str, int, int, int, tuple[str, ...]]) -> tuple[int, int, float]:
    out, seed, k, n_clips, shapes = args
    import torch

    torch.set_num_threads(1)
    path = _shard_path(Path(out), k)
    if path.exists():
        return k, 0, 0.0
    t0 = time.perf_counter()
    frames, measures, specs, xs, vs = [], [], [], [], []
    lo = k * SHARD_SIZE
    for i in range(lo, min(lo + SHARD_SIZE, n_clips)):
        spec = draw_spec(seed, i, shapes)
        try:
            clip, traj = render_clip(spec)
        except Exception as err:  # an unstable draw is skipped and recorded, not fatal
            specs.append({**spec.to_dict(), "failed": f"{type(err).__name__}: {err}"[:200]})
            continue
        sub = subsample_trajectory(traj, i)
        frames.append(clip)
        xs.append(sub["x"])
        vs.append(sub["v"])
        measures.append(motion_measures(sub))
        specs.append(spec.to_dict())
    ok = [s for s in specs if "failed" not in s]
    tmp = path.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        frames=np.stack(frames)
        if frames
        else np.zeros((0, CLIP_FRAMES, CLIP_SIZE, CLIP_SIZE, 3), np.uint8),
        traj_x=np.stack(xs) if xs else np.zeros((0, CLIP_FRAMES, 0, 3), np.float16),
        traj_v=np.stack(vs) if vs else np.zeros((0, CLIP_FRAMES, 0, 3), np.float16),
        t=np.arange(CLIP_FRAMES) * FRAME_DT,
        measures=np.array(json.dumps(measures)),
        specs=np.array(json.dumps(ok)),
        failed=np.array(json.dumps([s for s in specs if "failed" in s])),
    )
    os.replace(tmp, path)
    return k, len(frames), time.perf_counter() - t0


def generate(
    out: str | Path,
    clips: int,
    *,
    workers: int = 1,
    seed: int = 0,
    shapes: tuple[str, ...] = TRAIN_SHAPES,
    on_shard=None,
) -> dict[str, Any]:
    """Write ``clips`` clips as shards under ``out`` (skipping shards already there).

    ``on_shard(done_shards, total_shards, clips_in_shard)`` is called as shards finish.
    Writes ``out/dataset.json`` (seed, clips, shapes, frame layout). Returns it.
    """

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "schema": "motionphysics.prior-data/1",
        "seed": int(seed),
        "clips": int(clips),
        "shapes": list(shapes),
        "frames": CLIP_FRAMES,
        "size": CLIP_SIZE,
        "frame_dt": FRAME_DT,
        "shard_size": SHARD_SIZE,
    }
    return run_shards(
        out,
        meta,
        ("seed", "shapes", "frames", "size", "shard_size"),
        _make_shard,
        seed,
        clips,
        shapes,
        workers,
        on_shard,
    )


def run_shards(
    out: Path,
    meta: dict,
    keys: tuple[str, ...],
    make_shard,
    seed: int,
    clips: int,
    shapes,
    workers: int,
    on_shard=None,
) -> dict:
    """Write ``out/dataset.json`` (refusing an OUT made with other ``keys`` values) and make
    every shard of ``SHARD_SIZE`` clips with ``make_shard((out, seed, k, clips, shapes))``
    (a module-level function: ``spawn`` workers pickle it), in this process or a pool of
    ``workers``; ``on_shard(done, total, clips_in_shard)`` after each. Returns ``meta``.
    Shared by the tiny and the motion prior's ``prior data``."""
    from motionphysics.errors import UserInputError

    mfile = out / "dataset.json"
    if mfile.exists():
        old = json.loads(mfile.read_text())
        for key in keys:
            if old.get(key) != meta[key]:
                raise UserInputError(
                    f"{mfile}: {key} is {old.get(key)!r} there but {meta[key]!r} was asked; "
                    "use another OUT directory"
                )
    mfile.write_text(json.dumps(meta, indent=1))
    n_shards = (clips + SHARD_SIZE - 1) // SHARD_SIZE
    jobs = [(str(out), seed, k, clips, tuple(shapes)) for k in range(n_shards)]
    done = 0
    if workers <= 1:
        for job in jobs:
            _, n, _ = make_shard(job)
            done += 1
            if on_shard:
                on_shard(done, n_shards, n)
    else:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(workers) as pool:
            for _, n, _ in pool.imap_unordered(make_shard, jobs):
                done += 1
                if on_shard:
                    on_shard(done, n_shards, n)
    return meta


def load_shards(root: str | Path) -> tuple[np.ndarray, list[dict], list[dict]]:
    """All shards under ``root`` in shard order -> (frames uint8 [N,T,H,W,3], measures, specs).

    The measures are recomputed from the stored trajectories (so a change of
    :func:`motion_measures` applies to existing data)."""
    from motionphysics.errors import UserInputError

    root = Path(root)
    files = sorted(root.glob("shard-*[0-9].npz"))
    if not files:
        raise UserInputError(f"{root}: no shard-*.npz files (run `motionphysics prior data`)")
    frames, measures, specs = [], [], []
    for f in files:
        with np.load(f) as z:
            frames.append(z["frames"])
            specs += json.loads(str(z["specs"]))
            t = z["t"]
            for x, v in zip(z["traj_x"], z["traj_v"], strict=True):
                measures.append(motion_measures({"x": x, "v": v, "t": t}))
    return np.concatenate(frames), measures, specs
