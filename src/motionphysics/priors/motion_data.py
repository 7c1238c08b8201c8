"""Training clips for the embedded motion prior: simulated trajectories, no rendering.

``motionphysics prior data OUT`` (``--prior motion``, the default) writes
``OUT/shard-XXXXX.npz`` files. Each holds, per clip, the simulated states of a fixed
random subset of :data:`KEEP_PARTICLES` particles at the clip's :data:`CLIP_FRAMES` frames
(``x`` float32 [N, T, K, 3] m, ``F`` float32 [N, T, K, 3, 3], ``v`` float16 [N, T, K, 3]
m/s), the clip's frame times ``t`` [N, T] s, its ground height and gravity, the measured
motion (``measures``, JSON: :func:`motion_measures` with speeds Froude-scaled, see
:func:`clip_measures`) and the drawn ``specs`` (JSON). The
features the prior sees (:mod:`.motion_features`) are computed from these states when
the data is loaded, so a change of the features never needs new simulations.

A clip is one forward simulation through the code path of ``motionphysics simulate``
(``scene.prepare``, the pipeline's material resolution and simulation map,
``sim.build``): a builtin shape, a random compound of ellipsoids and boxes, or a slender
bar; its largest side drawn log-uniformly from 1 cm to 1 m; rotated; dropped from a
height drawn relative to its size onto a frictional floor, with a random initial
velocity (Froude-scaled: proportional to sqrt(g L)), sometimes a mid-clip impulse, and
gravity switched off in some clips (then thrown at the floor). Material: one of the 7
classes, every parameter drawn across the class's handbook range (log-uniform where the
catalogue says ``log``). The clip's duration is drawn too (frame spacing 0.03-0.08 s).

Balance: clip ``i`` has a target motion group (``i`` mod 9: the 8 groups of
:mod:`.captions` and "no group"); its setup is drawn from a proposal for that group (the
classes that can show it) and re-drawn, up to :data:`MAX_ATTEMPTS` times (more for the
rarest groups, :data:`MAX_ATTEMPTS_OF`), until the
measured group is the target (rejection sampling). The last attempt is kept when none
hits, so a data set holds every clip index, with its measured group.

Clip ``i`` of a data set with seed ``S`` is fully determined by ``(S, i)`` (attempt ``a``
draws from its own generator ``(S, i, a)``), so the data set is deterministic per seed
whatever the number of workers, and a killed generation resumes by skipping the shards
already on disk (each shard is written atomically).

This module holds no physics of its own.
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

from motionphysics.language.captions import GROUPS, motion_group

__all__ = [
    "CLIP_FRAMES",
    "HELD_OUT_SHAPES",
    "KEEP_PARTICLES",
    "MAX_ATTEMPTS",
    "MAX_ATTEMPTS_OF",
    "TRAIN_SHAPES",
    "MotionSpec",
    "clip_measures",
    "draw_motion_spec",
    "generate",
    "load_clips",
    "motion_measures",
    "run_shards",
    "simulate_clip",
]

CLIP_FRAMES = 16
"""Frames per clip (frame 0 = the initial state)."""
KEEP_PARTICLES = 256
"""Particles stored per clip (a fixed random subset)."""
GRID = 20
"""Cells along the longest side of the fitted domain."""
MAX_PARTICLES = 500
MAX_SUBSTEPS = 80
"""The clip's ``sim.max_substeps`` budget: the sim map compresses stiffness that cannot be
seen within it (a clip's cost is its substeps; stiff draws of small objects would
otherwise take 10x the others)."""
SHARD_SIZE = 10
MAX_ATTEMPTS = 3
"""Draws per clip before the rejection sampler keeps the last one."""
REFERENCE_SIZE = 0.3
"""[m] The object size the caption thresholds on absolute speeds were set for: speeds
are Froude-scaled to it (``v sqrt(REFERENCE_SIZE / L)``) before the captions read them."""
G0 = 9.8

TRAIN_SHAPES = ("sphere", "cube", "column", "rod", "bird", "compound", "slender")
"""Shapes drawn for training clips (``compound``: 2-3 primitives; ``slender``: one bar
or spindle with an aspect ratio of 4-12)."""
HELD_OUT_SHAPES = ("duck", "torus", "bird_simple")
"""Shapes never drawn for training clips: the held-out evaluation uses them."""

_DENSITY = {
    "elastic": (900.0, 1600.0),
    "plasticine": (1300.0, 2000.0),
    "metal": (2700.0, 8900.0),
    "foam": (30.0, 300.0),
    "sand": (1400.0, 1900.0),
    "newtonian": (800.0, 1400.0),
    "non_newtonian": (1000.0, 1500.0),
}

_PROPOSAL: dict[str | None, dict[str, float]] = {
    "bounces_high": {"elastic": 0.8, "foam": 0.2},
    "barely_bounces": {"elastic": 0.4, "foam": 0.2, "plasticine": 0.2, "metal": 0.2},
    "wobbles": {"elastic": 0.8, "foam": 0.2},
    "splashes": {"newtonian": 0.6, "non_newtonian": 0.4},
    "oozes": {"non_newtonian": 0.6, "newtonian": 0.4},
    "keeps_shape": {"metal": 0.5, "elastic": 0.3, "plasticine": 0.2},
    "crumbles": {"sand": 1.0},
    "squashes_flat": {"plasticine": 0.6, "non_newtonian": 0.2, "foam": 0.2},
    None: {c: 1.0 for c in _DENSITY},
}
"""Per target motion group, the probability of each material class in its proposal."""

TARGETS: tuple[str | None, ...] = (*GROUPS, None)

_SETUP: dict[str | None, dict[str, tuple[float, float]]] = {
    "bounces_high": {"drop": (1.0, 5.0), "E": (1e5, 1e8)},
    "barely_bounces": {"drop": (0.3, 3.0), "E": (1e6, 1e9)},
    "wobbles": {"drop": (0.05, 0.5), "E_rel": (3.0, 20.0), "nu": (0.45, 0.49), "vz": (-0.2, 0.0)},
    "splashes": {"drop": (0.5, 4.0)},
    "oozes": {
        "drop": (0.02, 0.3),
        "scale": (0.08, 0.6),
        "mu_rel": (1.0, 40.0),
        "tau_Y": (1.0, 50.0),
        "vz": (-0.2, 0.0),
    },
    "keeps_shape": {"drop": (0.05, 1.0)},
    "crumbles": {"drop": (0.05, 2.0)},
    "squashes_flat": {"drop": (0.1, 1.5), "tau_Y": (3e3, 1e5)},
}
"""Per target group, narrower draws of the drop height (over the object size), the size
[m] and some parameters (intersected with the class's range; a linear parameter such as
``nu`` is drawn uniformly in the given interval): the proposal's shift toward setups that
can show the motion. The caption is still what the simulated motion shows.

Two draws are relative to the object, because the motion depends on the ratio, not on
the value: ``E_rel`` draws E as a multiple of rho g L (its inverse is the strain of the
static sag under the object's own weight: a wobble needs a sag of a few per cent, soft
enough to swing at impact and stiff enough to come back; a fixed E range makes a 1 m
jelly sag flat and a 1 cm one rigid), ``mu_rel`` draws the viscosity as rho g L times a
slump time in seconds (an ooze is a flow still creeping at the clip's end, 0.45-1.2 s).
Both switch gravity on (the motions are gravity's). ``vz`` is the initial vertical
velocity over the Froude velocity sqrt(g L) (a wobble or an ooze is set down, not thrown
up)."""

MAX_ATTEMPTS_OF: dict[str | None, int] = {"wobbles": 6, "oozes": 6}
"""More attempts for the rarest groups (a soft solid that swings without bouncing off,
and a flow still creeping at the end, hit their target in about 1 draw of 6, the others
in about 1 of 2): rejection sampling toward a balanced data set."""


@dataclass(frozen=True)
class MotionSpec:
    """Everything that determines one clip (JSON-serialisable via ``to_dict``)."""

    index: int
    attempt: int
    target: str | None
    cls: str
    density: float
    params: dict[str, float]
    shape: str
    parts: list[dict[str, Any]] | None
    """``compound`` / ``slender``: [{kind: ellipsoid|box, centre [3], size [3]}]."""
    scale: float
    """Longest side of the object [m]."""
    rotate: list[tuple[str, float]]
    drop: float
    """Gap between the object's lowest point and the floor [m]."""
    velocity: tuple[float, float, float]
    """Initial velocity [m/s]."""
    gravity: float
    """|g| [m/s^2] (0: gravity off)."""
    impulse: dict[str, Any] | None
    """{force [3] m/s, start s} of a mid-clip push of the whole object, or None."""
    friction: float
    frame_dt: float
    """Seconds between frames."""

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["rotate"] = [list(r) for r in self.rotate]
        d["velocity"] = list(self.velocity)
        return d


def _draw_param(rng: np.random.Generator, ps) -> float:
    lo, hi = float(ps.low), float(ps.high)
    if getattr(ps, "default", None) is not None and rng.random() < 0.3:
        return float(ps.default)
    if ps.scale == "log" and lo > 0:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return float(rng.uniform(lo, hi))


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _target(index: int) -> str | None:
    """The motion group clip ``index`` is drawn toward (None: no group)."""
    return TARGETS[int(index) % len(TARGETS)]


def draw_motion_spec(
    seed: int, index: int, attempt: int = 0, shapes: tuple[str, ...] = TRAIN_SHAPES
) -> MotionSpec:
    """The random setup of attempt ``attempt`` of clip ``index`` (deterministic)."""
    from motionphysics.materials.catalog import MATERIALS
    from motionphysics.materials.catalog import spec as param_spec

    target = _target(index)
    rng = np.random.default_rng([int(seed), int(index), int(attempt), 11])
    prop = _PROPOSAL[target]
    classes = sorted(prop)
    p = np.array([prop[c] for c in classes])
    cls = classes[int(rng.choice(len(classes), p=p / p.sum()))]
    setup = _SETUP.get(target, {})
    params = {}
    for ps in MATERIALS[cls].params:
        if ps.name in setup:
            lo_p = max(float(ps.low), setup[ps.name][0])
            hi_p = min(float(ps.high), setup[ps.name][1])
            if lo_p < hi_p:
                log = ps.scale == "log"
                params[ps.name] = _logu(rng, lo_p, hi_p) if log else float(rng.uniform(lo_p, hi_p))
                continue
        params[ps.name] = _draw_param(rng, ps)
    lo, hi = _DENSITY[cls]
    density = _logu(rng, lo, hi)
    shape = shapes[int(rng.integers(len(shapes)))]
    parts = None
    if shape == "compound":
        parts = [
            {
                "kind": "ellipsoid" if rng.random() < 0.6 else "box",
                "centre": rng.uniform(-0.25, 0.25, 3).round(4).tolist(),
                "size": rng.uniform(0.2, 0.6, 3).round(4).tolist(),
            }
            for _ in range(int(rng.integers(2, 4)))
        ]
    elif shape == "slender":
        thick = 1.0 / float(rng.uniform(4.0, 12.0))
        parts = [
            {
                "kind": "box" if rng.random() < 0.5 else "ellipsoid",
                "centre": [0.0, 0.0, 0.0],
                "size": [1.0, thick, thick * float(rng.uniform(0.7, 1.4))],
            }
        ]
    scale = _logu(rng, *setup.get("scale", (0.01, 1.0)))
    rotate = [(ax, float(rng.uniform(-40, 40))) for ax in ("x", "y") if rng.random() < 0.6]
    if rng.random() < 0.7:
        rotate.append(("z", float(rng.uniform(0, 360))))
    gravity = G0 if rng.random() < 0.88 else 0.0
    for key, name in (("E_rel", "E"), ("mu_rel", "mu")):
        if key in setup and name in params:  # relative to rho g L, inside the class's range
            value = _logu(rng, *setup[key]) * density * G0 * scale
            ps = param_spec(cls, name)
            params[name] = float(min(max(value, float(ps.low)), float(ps.high)))
            gravity = G0
    vref = math.sqrt(G0 * scale)  # Froude velocity scale of the object
    drop = min(0.6, scale * _logu(rng, *setup.get("drop", (0.05, 3.0))))
    vel = [float(rng.normal(0, 0.4 * vref)), float(rng.normal(0, 0.4 * vref))]
    if gravity > 0:
        vel.append(float(rng.uniform(-1.5, 0.5) * vref))
    else:  # thrown at the floor: without gravity nothing else would reach it
        vel.append(-float(rng.uniform(0.8, 3.0) * vref))
    if "vz" in setup and gravity > 0:
        vel[2] = float(rng.uniform(*setup["vz"]) * vref)
    frame_dt = _logu(rng, 0.03, 0.08)
    impulse = None
    if rng.random() < 0.2:
        d = rng.normal(0, 1, 3)
        d[2] = abs(d[2])
        d = d / max(float(np.linalg.norm(d)), 1e-9)
        impulse = {
            "force": (d * rng.uniform(0.5, 2.5) * vref).round(5).tolist(),
            "start": float(rng.uniform(0.15, 0.5) * frame_dt * (CLIP_FRAMES - 1)),
        }
    return MotionSpec(
        index=int(index),
        attempt=int(attempt),
        target=target,
        cls=cls,
        density=density,
        params=params,
        shape=shape,
        parts=parts,
        scale=scale,
        rotate=rotate,
        drop=drop,
        velocity=(vel[0], vel[1], vel[2]),
        gravity=gravity,
        impulse=impulse,
        friction=float(rng.uniform(0.1, 0.9)),
        frame_dt=frame_dt,
    )


def _build_scene(spec: MotionSpec):
    """The Gaussian scene of ``spec`` (unit size, centred; colours do not matter here)."""
    import torch

    from motionphysics.scene import load_scene

    if spec.parts is None:
        return load_scene(f"builtin:{spec.shape}")
    import trimesh

    from motionphysics.scene import builtin as b

    parts = []
    for p in spec.parts:
        colour = b._solid((0.5, 0.5, 0.5))
        if p["kind"] == "ellipsoid":
            parts.append(b._ellipsoid(p["centre"], [0.5 * s for s in p["size"]], colour))
        else:
            m = trimesh.creation.box(extents=p["size"])
            m.apply_translation(p["centre"])
            parts.append(b._mesh_part(m, colour))
    return b._normalise(b._assemble(parts, count=2500, seed=spec.index)).to(torch.float32)


def _config(spec: MotionSpec, z_lowest: float):
    from motionphysics.config import config_from_dict

    forces = []
    if spec.impulse is not None:
        forces.append(
            {"type": "add_impulse", "force": spec.impulse["force"], "start": spec.impulse["start"]}
        )
    return config_from_dict(
        {
            "scene": {
                "source": "builtin:sphere",
                "scale": spec.scale,
                "rotate": [list(r) for r in spec.rotate],
                "translate": [0.0, 0.0, spec.drop - z_lowest],
                "max_particles": MAX_PARTICLES,
            },
            "material": {"class": spec.cls, "density": spec.density, **spec.params},
            "sim": {
                "grid": GRID,
                "frames": CLIP_FRAMES,
                "frame_dt": spec.frame_dt,
                "substeps": "auto",
                "max_substeps": MAX_SUBSTEPS,
                "gravity": [0.0, 0.0, -spec.gravity],
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
            "forces": forces,
        },
        "<prior data>",
    )


class _Quiet:
    def note(self, *_a) -> None:
        pass

    def advance(self, *_a) -> None:
        pass


def simulate_clip(spec: MotionSpec) -> dict[str, Any]:
    """Simulate ``spec`` -> ``{x [T,P,3] m, F [T,P,3,3], v [T,P,3] m/s, t [T] s, ground
    (floor height, m), gravity [3] m/s^2, substeps}`` (float32 numpy, all particles)."""
    from motionphysics.assembly import resolve_material, resolve_simulation, simulate_forward
    from motionphysics.errors import UserInputError
    from motionphysics.scene.prepare import prepare, transform_scene

    scene = _build_scene(spec)
    probe = _config(spec, 0.0)
    placed, _ = transform_scene(scene, spec.scale, probe.scene.rotate, (0.0, 0.0, 0.0))
    z_lowest = float(placed.means[:, 2].min())
    cfg = _config(spec, z_lowest)
    sim_scene = prepare(scene, cfg.scene, cfg.sim, list(cfg.boundary_conditions))
    material = resolve_material(cfg, None)["material"]
    res = resolve_simulation(material, cfg, sim_scene)
    if res.substeps > 2 * MAX_SUBSTEPS:
        raise UserInputError(
            f"{spec.cls} draw needs {res.substeps} substeps (cap {2 * MAX_SUBSTEPS})"
        )
    xs, Fs, vs, n = simulate_forward(
        sim_scene, cfg, material, res.values, "cpu", CLIP_FRAMES, _Quiet()
    )
    return {
        "x": xs,
        "F": Fs,
        "v": vs,
        "t": np.arange(CLIP_FRAMES) * spec.frame_dt,
        "ground": 0.0,
        "gravity": np.array([0.0, 0.0, -spec.gravity]),
        "substeps": int(n),
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


def clip_measures(x: np.ndarray, v: np.ndarray, t: np.ndarray, size: float | None = None):
    """:func:`motion_measures` of a clip with the absolute speed (``late_speed``)
    Froude-scaled to a :data:`REFERENCE_SIZE` object, so the caption rules read a 1 cm
    drop and a 1 m drop alike. ``size``: the object's largest side [m] (default: from the
    first frame)."""
    x = np.asarray(x, dtype=np.float64)
    if size is None:
        size = float(np.ptp(x[0], axis=0).max())
    m = motion_measures({"x": x, "v": np.asarray(v, np.float64), "t": np.asarray(t)})
    m["late_speed"] = float(m["late_speed"]) * math.sqrt(REFERENCE_SIZE / max(size, 1e-6))
    return m


def group_of(measures: dict[str, float], cls: str) -> str | None:
    m = dict(measures)
    m["granular"] = 1.0 if cls == "sand" else 0.0
    return motion_group(m)


def _subset(n: int, seed: int, index: int) -> np.ndarray:
    k = min(KEEP_PARTICLES, n)
    idx = np.random.default_rng([int(seed), int(index), 3]).choice(n, k, replace=False)
    return np.sort(idx)


def make_clip(seed: int, index: int, shapes: tuple[str, ...] = TRAIN_SHAPES) -> dict[str, Any]:
    """Clip ``index``: rejection-sampled toward its target group (see the module docstring).

    Returns ``{spec, group, measures, x, F, v, t, ground, gravity, attempts, failed}``
    (``x``/``F``/``v`` of the kept particle subset), or ``{spec, failed}`` when every
    attempt failed to simulate."""
    last: dict[str, Any] | None = None
    failures = []
    for a in range(MAX_ATTEMPTS_OF.get(_target(index), MAX_ATTEMPTS)):
        spec = draw_motion_spec(seed, index, a, shapes)
        try:
            traj = simulate_clip(spec)
        except (ImportError, MemoryError, KeyboardInterrupt):
            raise  # a broken install or a full machine is not an unstable draw
        except Exception as err:  # an unstable draw is recorded and re-drawn, not fatal
            failures.append(f"{type(err).__name__}: {err}"[:200])
            continue
        idx = _subset(traj["x"].shape[1], seed, index)
        x, F, v = traj["x"][:, idx], traj["F"][:, idx], traj["v"][:, idx]
        size = float(np.ptp(traj["x"][0], axis=0).max())
        m = clip_measures(x, v, traj["t"], size)
        g = group_of(m, spec.cls)
        last = {
            "spec": spec.to_dict(),
            "group": g,
            "measures": m,
            "x": np.asarray(x, np.float32),
            "F": np.asarray(F, np.float32),
            "v": np.asarray(v, np.float16),
            "t": np.asarray(traj["t"], np.float32),
            "ground": float(traj["ground"]),
            "gravity": np.asarray(traj["gravity"], np.float32),
            "attempts": a + 1,
            "failed": failures,
        }
        if spec.target is None or g == spec.target:
            break
    if last is None:
        return {"spec": draw_motion_spec(seed, index, 0, shapes).to_dict(), "failed": failures}
    return last


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
    clips, failed = [], []
    lo = k * SHARD_SIZE
    for i in range(lo, min(lo + SHARD_SIZE, n_clips)):
        c = make_clip(seed, i, shapes)
        if "x" in c:
            clips.append(c)
        else:
            failed.append(c)
    k_p = KEEP_PARTICLES
    tmp = path.with_suffix(".tmp.npz")

    def stack(key, shape, dtype):
        return np.stack([c[key] for c in clips]) if clips else np.zeros(shape, dtype)

    # clips with fewer particles than KEEP_PARTICLES are padded by repeating their last one
    for c in clips:
        for key in ("x", "F", "v"):
            a = c[key]
            if a.shape[1] < k_p:
                pad = np.repeat(a[:, -1:], k_p - a.shape[1], axis=1)
                c[key] = np.concatenate([a, pad], axis=1)
    np.savez(
        tmp,
        x=stack("x", (0, CLIP_FRAMES, k_p, 3), np.float32),
        F=stack("F", (0, CLIP_FRAMES, k_p, 3, 3), np.float32),
        v=stack("v", (0, CLIP_FRAMES, k_p, 3), np.float16),
        t=stack("t", (0, CLIP_FRAMES), np.float32),
        ground=np.array([c["ground"] for c in clips], np.float32),
        gravity=stack("gravity", (0, 3), np.float32),
        measures=np.array(json.dumps([c["measures"] for c in clips])),
        groups=np.array(json.dumps([c["group"] for c in clips])),
        attempts=np.array([c["attempts"] for c in clips], np.int32),
        specs=np.array(json.dumps([c["spec"] for c in clips])),
        failed=np.array(json.dumps([{"spec": c["spec"], "failed": c["failed"]} for c in failed])),
    )
    os.replace(tmp, path)
    return k, len(clips), time.perf_counter() - t0


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
    Writes ``out/dataset.json``. Returns it."""

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "schema": "motionphysics.motion-data/1",
        "seed": int(seed),
        "clips": int(clips),
        "shapes": list(shapes),
        "frames": CLIP_FRAMES,
        "particles": KEEP_PARTICLES,
        "shard_size": SHARD_SIZE,
        "max_attempts": {
            "default": MAX_ATTEMPTS,
            **{str(k): v for k, v in MAX_ATTEMPTS_OF.items()},
        },
    }
    return run_shards(
        out,
        meta,
        ("schema", "seed", "shapes", "frames", "particles", "shard_size"),
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
    """
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


def shard_files(root: str | Path) -> list[Path]:
    """The finished shards under ``root`` in shard order (not the ``.tmp`` of one being
    written)."""
    return sorted(Path(root).glob("shard-*[0-9].npz"))


def shard_summary(root: str | Path) -> dict[str, Any]:
    """What the shards under ``root`` hold: ``{"clips": kept clips, "failed": clips whose
    every attempt failed to simulate, "reasons": {first failure line: count}}``."""
    clips, failed, reasons = 0, 0, {}
    for f in shard_files(root):
        with np.load(f) as z:
            clips += len(json.loads(str(z["groups"])))
            for c in json.loads(str(z["failed"])) if "failed" in z.files else []:
                failed += 1
                why = (c.get("failed") or ["no attempt recorded"])[0]
                reasons[why] = reasons.get(why, 0) + 1
    return {"clips": clips, "failed": failed, "reasons": reasons}


def load_clips(root: str | Path, *, max_shards: int | None = None) -> dict[str, Any]:
    """All shards under ``root`` in shard order -> ``{x [N,T,K,3], F [N,T,K,3,3], t [N,T],
    ground [N], gravity [N,3], groups [str|None], measures, specs}`` (float32 arrays)."""
    from motionphysics.errors import UserInputError

    root = Path(root)
    files = shard_files(root)
    if max_shards is not None:
        files = files[:max_shards]
    if not files:
        raise UserInputError(f"{root}: no shard-*.npz files (run `motionphysics prior data`)")
    parts: dict[str, list] = {k: [] for k in ("x", "F", "t", "ground", "gravity")}
    groups, measures, specs = [], [], []
    for f in files:
        with np.load(f) as z:
            for k in parts:
                parts[k].append(np.asarray(z[k], np.float32))
            groups += json.loads(str(z["groups"]))
            measures += json.loads(str(z["measures"]))
            specs += json.loads(str(z["specs"]))
    out: dict[str, Any] = {k: np.concatenate(v) for k, v in parts.items()}
    out.update(groups=groups, measures=measures, specs=specs)
    return out
