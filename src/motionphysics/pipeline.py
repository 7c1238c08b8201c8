"""The main job end to end: prompt + scene + config -> a finished run directory.

Stages (each timed; the names appear in the progress display, ``params.json`` and the
report)::

    load scene         load_scene + prepare -> SimScene (particles in the MPM domain)
    reference render   the rest state from the run camera (plots/reference.png)
    estimate material  init backend (kb | llm | median | naive) from the prompt (+ image)
    resolve material   config ``material:`` overrides, handbook clamps, sim map
    optimise           only when optimize.prior != none (the plug-in point)
    simulate           build_simulation(...).run(frames) -> x [T,P,3], F [T,P,3,3]
    render             splats follow the particles -> video.mp4
    write outputs      trajectory.npz, metrics.json, plots/, splats/, report.html

Every file goes through :class:`~motionphysics.io.rundir.RunDirectory` (atomic
writes). ``params.json`` is written as soon as the run starts with ``partial: true``
and rewritten at each stage, so a run killed or interrupted at any point leaves a
consistent directory that says how far it got; the last write flips it to
``partial: false``. ``run.yaml`` is the fully resolved config (material filled in,
camera resolved, seed, versions): re-running it reproduces the run.

This module orchestrates; it holds no physics, rendering or material knowledge of
its own (those live in scene, materials, init, sim, render).
"""

from __future__ import annotations

import math
import platform
import signal
import sys
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics import __version__
from motionphysics.config import (
    MATERIAL_CLASSES,
    RunConfig,
    SurfaceCollider,
    config_from_dict,
    config_to_dict,
)
from motionphysics.errors import RunInterrupted, SimulationError, UserInputError
from motionphysics.progress import Progress

__all__ = [
    "PARAMS_SCHEMA",
    "RunResult",
    "load_run_config",
    "resolve_paths",
    "read_params_file",
    "render_video",
    "run_pipeline",
    "simulate_forward",
    "versions",
    "summary_text",
    "write_run_trajectory",
]

PARAMS_SCHEMA = "motionphysics.params/1"
UNITS = {
    "density": "kg/m^3",
    "E": "Pa",
    "nu": "-",
    "tau_Y": "Pa",
    "eta": "-",
    "theta_fric": "deg",
    "mu": "Pa s",
    "kappa": "Pa",
    "n": "-",
}
INIT_BACKENDS = ("kb", "llm", "median", "naive")


# --------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------
def versions() -> dict[str, str]:
    """Versions of the packages that shape a run's numbers (recorded in run.yaml)."""
    out = {"motionphysics": __version__, "python": platform.python_version()}
    for dist, key in (("torch", "torch"), ("warp-lang", "warp"), ("numpy", "numpy")):
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def _set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    keys = dotted.split(".")
    for k in keys[:-1]:
        sub = node.get(k)
        if sub is None:
            sub = {}
            node[k] = sub
        if not isinstance(sub, dict):
            raise UserInputError(f"{k}: expected a mapping to set {dotted}")
        node = sub
    node[keys[-1]] = value


def resolve_paths(data: dict[str, Any], base: Path | None) -> dict[str, Any]:
    """Make file paths in a config mapping absolute.

    A relative ``scene.source`` / ``camera.cameras_json`` is looked up beside the
    config file first, then in the working directory (so a config and its assets can
    be moved together, and ``run.yaml`` works from anywhere).
    """

    def fix(value: Any) -> Any:
        if not isinstance(value, str) or value.startswith("builtin:") or not value.strip():
            return value
        p = Path(value).expanduser()
        if p.is_absolute():
            return str(p)
        if base is not None and (base / p).exists():
            return str((base / p).resolve())
        if p.exists():
            return str(p.resolve())
        return value  # left as given: the loader reports it missing, naming it as written

    for section, key in (("scene", "source"), ("camera", "cameras_json")):
        sec = data.get(section)
        if isinstance(sec, dict) and key in sec:
            sec[key] = fix(sec[key])
    return data


def load_run_config(
    path: str | Path | None, overrides: Mapping[str, Any] | None = None
) -> RunConfig:
    """Read a YAML run config (or the defaults when ``path`` is None), apply overrides.

    ``overrides`` maps dotted config paths (``"prompt"``, ``"optimize.iterations"``,
    ``"device"``...) to values from the command line; they win over the file. Errors
    name the file (or the flag) and the field, on one line.
    """
    import yaml

    origin = "<defaults>"
    data: dict[str, Any] = {}
    base = None
    if path is not None:
        p = Path(path)
        origin = str(p)
        if not p.is_file():
            raise UserInputError(f"{p}: config file not found")
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except yaml.YAMLError as err:
            raise UserInputError(f"{p}: not valid YAML ({str(err).splitlines()[0]})") from None
        except UnicodeDecodeError:
            raise UserInputError(f"{p}: not a text file (expected a YAML run config)") from None
        if not isinstance(data, dict):
            raise UserInputError(f"{p}: expected a YAML mapping at the top level")
        base = p.resolve().parent
    data = dict(data)
    data.pop("versions", None)  # informational in run.yaml; never an input
    for key, value in (overrides or {}).items():
        if value is not None:
            _set_path(data, key, value)
    return config_from_dict(resolve_paths(data, base), origin)


def read_params_file(path: str | Path) -> dict[str, Any]:
    """Read ``--params FILE``: a run's ``params.json`` or a plain ``{class, density, params}``.

    Returns ``{"class": str, "density": float, "params": {name: float}}`` (not yet
    validated against the catalogue; that happens with the config overrides).
    """
    import json

    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"{p}: params file not found")
    try:
        data = json.loads(p.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise UserInputError(f"{p}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise UserInputError(f"{p}: expected a JSON object with class, density, params")
    cls = data.get("class")
    if not isinstance(cls, str):
        raise UserInputError(
            f"{p}: field 'class' missing (expected one of {', '.join(MATERIAL_CLASSES)})"
        )
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise UserInputError(f"{p}: field 'params' must be an object of parameter values (SI)")
    if "density" not in data:
        raise UserInputError(f"{p}: field 'density' missing (expected kg/m^3)")
    return {"class": cls, "density": data["density"], "params": dict(params), "origin": str(p)}


# --------------------------------------------------------------------------------------
# material
# --------------------------------------------------------------------------------------
def _range_centre(cls: str, name: str) -> float:
    """Centre of a parameter's handbook range (geometric for log-scaled ones)."""
    from motionphysics.materials.catalog import spec

    ps = spec(cls, name)
    if getattr(ps, "default", None) is not None:
        return float(ps.default)
    lo, hi = float(ps.low), float(ps.high)
    if getattr(ps, "scale", "linear") == "log" and lo > 0:
        return math.sqrt(lo * hi)
    return 0.5 * (lo + hi)


def _estimate(prompt: str, image, backend: str, progress: Progress | None = None) -> dict[str, Any]:
    """Run an init backend (CONTRACTS.md, "init").

    ``image`` is the reference render, uint8 [H, W, 3]. Returns ``{class, density,
    params, backend, raw, clamps, estimate}`` (``estimate``: the backend's full record).
    """
    from motionphysics.init import EstimateOptions, estimate

    # The kb backend announces its model load on stderr; keep that off a quiet run.
    announce = progress is not None and progress.verbose
    est = estimate(prompt, image=image, backend=backend, options=EstimateOptions(announce=announce))
    return {
        "class": est.cls,
        "density": float(est.density),
        "params": {k: float(v) for k, v in est.values.items()},
        "backend": est.backend,
        "raw": est.raw_answer,
        "clamps": [c.to_dict() for c in est.clamped],
        "estimate": est.to_dict(),
    }


def resolve_material(
    cfg: RunConfig, estimate: dict[str, Any] | None, base: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Combine an estimate (or a params file) with the config's ``material:`` block.

    Precedence per field: config ``material:`` > ``base`` (``--params`` file) >
    ``estimate``; a field none of them gives (the config changed the class) takes the
    centre of the class's handbook range. Out-of-range values are clamped into the
    range and recorded. Returns ``{"material": MaterialParams, "clamps": [...],
    "sources": {name: str}, "overrides": {...}, "class_override": bool}``.
    """
    from motionphysics.materials.catalog import MATERIALS, normalise_class, validate

    mat = cfg.material
    given = mat.overrides()
    start = base if base is not None else estimate
    start_name = "params file" if base is not None else (estimate or {}).get("backend", "estimate")
    if mat.class_ is not None:
        cls = normalise_class(mat.class_, field="material.class")
    elif start is not None and start.get("class") is not None:
        cls = normalise_class(start["class"], field=f"{start_name}.class")
    else:
        raise UserInputError(
            "material.class: missing (give it in the config or pass --params FILE)"
        )
    names = MATERIALS[cls].names
    same_class = (
        start is not None
        and start.get("class") is not None
        and normalise_class(start["class"], field=f"{start_name}.class") == cls
    )
    if base is not None and same_class:
        stray = sorted(k for k in (base.get("params") or {}) if k not in names)
        if stray:
            raise UserInputError(
                f"{base.get('origin', 'params file')}: parameter(s) {', '.join(stray)} do not belong "
                f"to class {cls} (expected {', '.join(names)})"
            )
    values: dict[str, float] = {}
    sources: dict[str, str] = {}
    extra = sorted(k for k in given if k != "density" and k not in names)
    if extra:
        raise UserInputError(
            f"material: parameter(s) {', '.join(extra)} do not belong to class {cls} "
            f"(expected {', '.join(names)})"
        )
    for name in ("density", *names):
        if name in given:
            values[name] = given[name]
            sources[name] = "config"
            continue
        sval = None
        if start is not None and (same_class or name == "density"):
            sval = (
                start.get("density") if name == "density" else (start.get("params") or {}).get(name)
            )
        if sval is not None:
            values[name] = sval
            sources[name] = start_name
        else:
            values[name] = _range_centre(cls, name)
            sources[name] = f"range centre of {cls}"
    density = values.pop("density")
    params, clamps = validate(
        cls, values, density=density, on_out_of_range="clamp", origin="material"
    )
    return {
        "material": params,
        "clamps": [c.to_dict() for c in clamps],
        "sources": sources,
        "overrides": given,
        "class_override": mat.class_ is not None and (start is None or not same_class),
    }


def _map_to_sim(material, cfg: RunConfig, sim_scene) -> tuple[dict[str, float], dict[str, Any]]:
    """Physical -> simulation values; picks substeps (``auto``: from the CFL limit)."""
    from motionphysics.materials.simmap import SimContext, physical_to_sim

    dx = float(sim_scene.dx)
    frame_dt = float(cfg.sim.frame_dt)
    lo = np.asarray(_np(sim_scene.particles)).min(0)
    hi = np.asarray(_np(sim_scene.particles)).max(0)
    length = float(np.max(hi - lo))
    gravity = float(np.linalg.norm(np.asarray(cfg.sim.gravity, dtype=np.float64)))
    if cfg.sim.substeps == "auto":
        dt = frame_dt / 512
        ctx = SimContext(
            dx=dx, dt=dt, density=float(material.density), length=length, gravity=gravity
        )
        sim = physical_to_sim(material, ctx)
        from motionphysics.sim.solver import auto_substeps

        substeps = int(auto_substeps({"class": material.cls, **sim}, dx, frame_dt))
    else:
        substeps = int(cfg.sim.substeps)
        ctx = SimContext(
            dx=dx,
            dt=frame_dt / substeps,
            density=float(material.density),
            length=length,
            gravity=gravity,
        )
        sim = physical_to_sim(material, ctx)
    sim = {k: float(v) for k, v in sim.items()}
    return sim, {
        "dx": dx,
        "dt": frame_dt / substeps,
        "substeps": substeps,
        "frame_dt": frame_dt,
        "length": length,
        "grid_dims": [int(v) for v in sim_scene.grid_dims],
    }


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


# --------------------------------------------------------------------------------------
# camera
# --------------------------------------------------------------------------------------
def _ground_height(cfg: RunConfig, xy_centre: np.ndarray, up: np.ndarray) -> float | None:
    """Height (along ``up``) of the highest upward-facing collider plane under the object."""
    best = None
    for bc in cfg.boundary_conditions:
        if isinstance(bc, SurfaceCollider) and bc.mode != "cut":
            n = np.asarray(bc.normal, dtype=np.float64)
            n = n / max(np.linalg.norm(n), 1e-12)
            if float(n @ up) > 0.7:
                # plane n.(p - point) = 0, evaluated under the object's centre
                p0 = np.asarray(bc.point, dtype=np.float64)
                c = xy_centre.copy()
                # move c along up until it is on the plane
                s = float(n @ (p0 - c)) / float(n @ up)
                h = float((c + s * up) @ up)
                best = h if best is None else max(best, h)
    return best


def _up(cfg: RunConfig) -> np.ndarray:
    g = np.asarray(cfg.sim.gravity, dtype=np.float64)
    n = np.linalg.norm(g)
    return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])


def _object_box(sim_scene) -> tuple[np.ndarray, np.ndarray]:
    """Robust bounding box [3], [3] of the visible splat centres [m] (0.5 / 99.5 percentiles)."""
    pts = _np(sim_scene.splats.means).astype(np.float64)
    return np.percentile(pts, 0.5, axis=0), np.percentile(pts, 99.5, axis=0)


def _fit_radius(corners: np.ndarray, cam, fill: float = 0.9) -> float:
    """Smallest orbit radius at which every corner [K, 3] projects inside ``fill`` of the image."""
    import torch

    from motionphysics.render.camera import orbit_camera

    pts = torch.as_tensor(corners, dtype=torch.float64)

    def fits(r: float) -> bool:
        c = orbit_camera(cam.azimuth, cam.elevation, r, cam.look_at, cam.fov, cam.width, cam.height)
        uv, z = c.project(pts)
        if bool((z <= 1e-3).any()):
            return False
        u = (uv[:, 0] - c.cx) / (0.5 * c.width)
        v = (uv[:, 1] - c.cy) / (0.5 * c.height)
        return bool((u.abs() <= fill).all() and (v.abs() <= fill).all())

    lo, hi = 1e-3, 1.0
    while not fits(hi):
        hi *= 2.0
        if hi > 1e7:
            raise UserInputError(
                "camera: could not frame the scene automatically; set camera.radius"
            )
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def resolve_camera(cfg: RunConfig, sim_scene) -> tuple[RunConfig, dict[str, Any]]:
    """The run camera; when the config leaves ``radius`` and ``look_at`` unset, frame the scene.

    Auto-framing keeps in view the object and, when there is a ground (the highest
    upward-facing collider plane under the object), the ground below it widened
    sideways by an eighth of the object's size so material spreading on the ground
    stays visible. It searches the orbit radius at which all of that fits in 90 % of
    the image. Without a ground collider the floor of the simulation domain plays the
    ground's part when it is near. Returns the config with the resolved camera written in (so ``run.yaml``
    reproduces the view) and a note for ``params.json``.
    """
    cam = cfg.camera
    explicit = cam.model_fields_set
    if cam.cameras_json or {"radius", "look_at"} & explicit:
        return cfg, {"framing": "config"}
    lo, hi = _object_box(sim_scene)
    up = _up(cfg)
    size = float(np.max(hi - lo))
    box_lo, box_hi = lo.copy(), hi.copy()
    ground = _ground_height(cfg, 0.5 * (lo + hi), up)
    if ground is None and up[2] > 0.99 and np.linalg.norm(cfg.sim.gravity) > 0:
        # No ground collider: a falling object stops at the domain floor; keep it in view
        # when that floor is near (a user-given domain may be far larger than the object).
        floor = float(_np(sim_scene.domain_lo)[2]) + 2.0 * float(sim_scene.dx)
        if lo[2] - floor < 3.0 * size:
            ground = floor
    if ground is not None and abs(up[2]) > 0.99:
        box_lo[2] = min(box_lo[2], ground) if up[2] > 0 else box_lo[2]
        box_hi[2] = box_hi[2] if up[2] > 0 else max(box_hi[2], ground)
        box_lo[:2] -= 0.12 * size
        box_hi[:2] += 0.12 * size
    corners = np.array(
        [
            [x, y, z]
            for x in (box_lo[0], box_hi[0])
            for y in (box_lo[1], box_hi[1])
            for z in (box_lo[2], box_hi[2])
        ]
    )
    look_at = tuple(float(v) for v in 0.5 * (box_lo + box_hi))
    probe = cam.model_copy(update={"look_at": look_at})
    radius = _fit_radius(corners, probe)
    new_cam = cam.model_copy(update={"look_at": look_at, "radius": float(radius)})
    return cfg.model_copy(update={"camera": new_cam}), {"framing": "auto (object and ground)"}


def ground_splats(cfg: RunConfig, sim_scene) -> dict[str, Any] | None:
    """Static splats drawing the ground as a grey checker floor (render only; not simulated).

    Drawn when ``camera.show_ground`` is on and a surface collider faces up under the
    object. A square centred below it, of half-side max(1.5 x object size, 1.2 x camera
    radius), checker cells of a sixth of the object's size (at least three splats wide). Returns ``{means [G,3] m, covs [G,3,3] m^2, colors [G,3],
    opacities [G]}`` float32 tensors, or None.
    """
    import torch

    if not getattr(cfg.camera, "show_ground", True):
        return None
    up = _up(cfg)
    if abs(up[2]) < 0.99:
        return None
    lo, hi = _object_box(sim_scene)
    centre = 0.5 * (lo + hi)
    ground = _ground_height(cfg, centre, up)
    if ground is None:
        return None
    size = max(float(np.max(hi - lo)), 1e-3)
    # Wide enough to reach the edges of the view (the camera looks at the object from
    # ``radius`` away), so the floor does not read as a small mat under a distant camera.
    half = max(1.5 * size, 1.2 * float(cfg.camera.radius))
    n = 80
    step = 2 * half / n
    g = (np.arange(n) + 0.5) * step - half
    gx, gy = np.meshgrid(centre[0] + g, centre[1] + g, indexing="ij")
    z = ground - 0.004 * size
    means = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], -1)
    cell = max(size / 6, 3.0 * step)
    parity = (
        np.floor((gx.ravel() - centre[0]) / cell) + np.floor((gy.ravel() - centre[1]) / cell)
    ) % 2
    colors = np.where(parity[:, None] == 0, [0.80, 0.80, 0.78], [0.66, 0.67, 0.66])
    sxy = 0.62 * step
    covs = np.zeros((means.shape[0], 3, 3))
    covs[:, 0, 0] = covs[:, 1, 1] = sxy**2
    covs[:, 2, 2] = (0.002 * size) ** 2
    f32 = torch.float32
    return {
        "means": torch.as_tensor(means, dtype=f32),
        "covs": torch.as_tensor(covs, dtype=f32),
        "colors": torch.as_tensor(colors, dtype=f32),
        "opacities": torch.full((means.shape[0],), 0.98, dtype=f32),
    }


def render_view(sim_scene, x, F, camera, background, ground: dict[str, Any] | None = None):
    """One frame: object splats following particles ``x`` [P,3] m, ``F`` [P,3,3] (+ ground).

    Returns rgb [H, W, 3] float32 in [0, 1] (torch, no autograd needed by callers here).
    """
    import torch

    from motionphysics.render.deform import deform_splats
    from motionphysics.render.rasterize import rasterize

    splats = sim_scene.splats
    x = torch.as_tensor(x, dtype=torch.float32)
    F = torch.as_tensor(F, dtype=torch.float32)
    means, covs, colors = deform_splats(
        splats, x, F, sim_scene.splat_parent.long(), sim_scene.splat_offset.to(x), camera
    )
    opac = splats.opacities.to(x)
    if ground is not None:
        means = torch.cat([means, ground["means"]])
        covs = torch.cat([covs, ground["covs"]])
        colors = torch.cat([colors.clamp(0, 1), ground["colors"]])
        opac = torch.cat([opac, ground["opacities"]])
    return rasterize(means, covs, colors, opac, camera, background).rgb


# --------------------------------------------------------------------------------------
# the run
# --------------------------------------------------------------------------------------
@dataclass
class RunResult:
    run_dir: Path
    params: dict[str, Any]
    metrics: dict[str, Any] | None
    timings: dict[str, float]
    video: Path | None
    config: RunConfig
    files: list[str] = field(default_factory=list)


@contextmanager
def _no_sigint():
    """Hold Ctrl-C off while the final bookkeeping of an interrupted run is written."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _seed_everything(seed: int) -> None:
    import random

    import torch

    random.seed(seed)
    np.random.seed(seed % (2**32))  # noqa: NPY002 - seeds legacy global users (third-party code)
    torch.manual_seed(seed)


def _fps(frame_dt: float) -> float:
    return max(1.0, min(60.0, 1.0 / frame_dt))


def run_pipeline(
    cfg: RunConfig,
    out: str | Path,
    *,
    init_backend: str = "kb",
    params_file: str | Path | None = None,
    optimise: bool = True,
    resume: bool = False,
    force: bool = False,
    progress: Progress | None = None,
    config_origin: str = "<config>",
    command: str = "run",
) -> RunResult:
    """Run the main job and write the run directory at ``out``.

    ``optimise=False`` is ``motionphysics simulate`` (forward only; material from the
    config's ``material:`` block, or ``params_file``, completed by ``init_backend``
    when the block is incomplete). Raises UserInputError / SimulationError /
    RunInterrupted (the directory then holds a consistent partial run).
    """
    from motionphysics.io.rundir import RunDirectory
    from motionphysics.runtime import check_device, set_threads

    if init_backend not in INIT_BACKENDS:
        raise UserInputError(
            f"--init: expected one of {', '.join(INIT_BACKENDS)}, got {init_backend!r}"
        )
    device = check_device(cfg.device)
    if optimise and cfg.optimize.prior != "none":
        _check_prior_available(cfg)
    progress = progress or Progress(quiet=True)
    rd = RunDirectory(out, resume=resume, force=force)
    t_start = time.perf_counter()
    seed = int(cfg.optimize.seed)
    set_threads()
    _seed_everything(seed)

    state: dict[str, Any] = {
        "schema": PARAMS_SCHEMA,
        "command": command,
        "prompt": cfg.prompt,
        "partial": True,
        "status": "running",
        "stage": "start",
        "seed": seed,
        "device": device,
        "versions": versions(),
        "history": [],
        "timings": progress.timings,
    }

    def save_params() -> None:
        state["timings"] = dict(progress.timings)
        rd.write_json("params.json", state)

    def save_run_yaml(c: RunConfig) -> None:
        data = config_to_dict(c)
        data["versions"] = versions()
        rd.write_yaml("run.yaml", data)

    save_run_yaml(cfg)
    save_params()

    @contextmanager
    def stage(name: str, total: int | None = None):
        state["stage"] = name
        save_params()  # a run killed now says which stage it was in
        with progress.stage(name, total) as st:
            yield st
        save_params()

    written: list[str] = ["run.yaml", "params.json"]
    try:
        # ---- scene -------------------------------------------------------------------
        with stage("load scene"):
            from motionphysics.scene import load_scene
            from motionphysics.scene.prepare import prepare

            scene = load_scene(cfg.scene.source)
            sim_scene = prepare(scene, cfg.scene, cfg.sim, list(cfg.boundary_conditions))
            n_particles = int(_np(sim_scene.particles).shape[0])
            state["scene"] = {
                "source": cfg.scene.source,
                "splats": int(sim_scene.splats.num),
                "particles": n_particles,
                "interior_particles": int(getattr(sim_scene, "n_interior", 0)),
                "domain_lo": [float(v) for v in _np(sim_scene.domain_lo)],
                "domain_hi": [float(v) for v in _np(sim_scene.domain_hi)],
                "dx": float(sim_scene.dx),
                "grid_dims": [int(v) for v in sim_scene.grid_dims],
            }
            progress.log(f"scene: {sim_scene.splats.num} splats, {n_particles} particles")

        # ---- camera + reference render -----------------------------------------------
        with stage("reference render"):
            import torch

            from motionphysics.render.camera import camera_from_config

            cfg, cam_note = resolve_camera(cfg, sim_scene)
            state["camera"] = {**cam_note, **config_to_dict(cfg)["camera"]}
            camera = camera_from_config(cfg.camera)
            background = tuple(float(v) for v in cfg.camera.background)
            ground = ground_splats(cfg, sim_scene)
            P = int(_np(sim_scene.particles).shape[0])
            with torch.no_grad():
                ref = render_view(
                    sim_scene,
                    sim_scene.particles,
                    torch.eye(3).expand(P, 3, 3),
                    camera,
                    background,
                    ground,
                )
            ref_np = (np.clip(_np(ref), 0, 1) * 255 + 0.5).astype(np.uint8)
            _write_png(rd, "plots/reference.png", ref_np)
            written.append("plots/reference.png")
            save_run_yaml(cfg)

        # ---- material ----------------------------------------------------------------
        base = read_params_file(params_file) if params_file is not None else None
        estimate = None
        need_estimate = base is None and not _material_complete(cfg)
        if need_estimate:
            with stage("estimate material"):
                estimate = _estimate(cfg.prompt, ref_np, init_backend, progress)
                progress.log(f"estimate ({init_backend}): {estimate['class']}")
        with stage("resolve material"):
            res = resolve_material(cfg, estimate, base)
            material = res["material"]
            sim_values, sim_ctx = _map_to_sim(material, cfg, sim_scene)
            backend = (
                "params file"
                if base is not None
                else estimate["backend"]
                if estimate is not None
                else "config"
            )
            state.update(_material_record(material, sim_values, sim_ctx))
            state["provenance"] = {
                "backend": backend,
                "params_file": str(params_file) if params_file is not None else None,
                "raw_answer": estimate.get("raw") if estimate else None,
                "estimate": estimate.get("estimate") if estimate else None,
                "clamps": res["clamps"],
                "estimate_clamps": estimate.get("clamps", []) if estimate else [],
                "overrides": res["overrides"],
                "class_override": res["class_override"],
                "sources": res["sources"],
            }
            # run.yaml: the material that was simulated (before any optimisation), so
            # re-running the file reproduces the run.
            mat_block = {
                "class": material.cls,
                "density": float(material.density),
                **{k: float(v) for k, v in material.values.items()},
            }
            cfg = config_from_dict({**config_to_dict(cfg), "material": mat_block}, config_origin)
            save_run_yaml(cfg)

        # ---- optimisation plug-in ----------------------------------------------------
        if optimise and cfg.optimize.prior != "none" and cfg.optimize.iterations > 0:
            with stage("optimise", total=cfg.optimize.iterations) as st:
                opt = _optimise(cfg, sim_scene, material, camera, rd, resume, st)
                material, sim_values = opt["material"], opt["sim"]
                state.update(_material_record(material, sim_values, sim_ctx))
                state["history"] = opt["history"]
                state["optimise"] = {
                    k: v for k, v in opt.items() if k not in ("material", "sim", "history")
                }
                written += ["log.jsonl", "checkpoint.pt"]

        # ---- simulate ----------------------------------------------------------------
        frames = int(cfg.sim.frames)
        with stage("simulate", total=frames) as st:
            xs, Fs, vs, substeps = simulate_forward(
                sim_scene, cfg, material, sim_values, device, frames, st
            )
            state["sim_context"]["substeps"] = substeps
            state["sim_context"]["dt"] = cfg.sim.frame_dt / substeps

        # ---- render ------------------------------------------------------------------
        with stage("render", total=frames) as st:
            video = render_video(rd, sim_scene, xs, Fs, camera, background, ground, cfg, st)
            written.append("video.mp4")

        # ---- outputs -----------------------------------------------------------------
        with stage("write outputs"):
            traj = write_run_trajectory(rd, sim_scene, xs, Fs, vs, cfg, material)
            written.append("trajectory.npz")
            metrics = write_metrics(rd, traj)
            written.append("metrics.json")
            plots = _write_plots(rd, video, traj, metrics, cfg, state)
            written += plots
        if cfg.export_ply:
            with stage("export splats", total=frames) as st:
                from motionphysics.io.export import export_splats

                export_splats(sim_scene, xs, Fs, rd.path / "splats", on_frame=st.advance)
                written.append("splats/")

        state["partial"] = False
        state["status"] = "complete"
        state["stage"] = "done"
        state["wall_time_s"] = time.perf_counter() - t_start
        save_params()
        _write_report_safe(rd, state, cfg, metrics, plots)
        written.append("report.html")
        save_params()
        return RunResult(
            rd.path,
            dict(state),
            metrics,
            dict(progress.timings),
            rd.path / "video.mp4",
            cfg,
            written,
        )
    except KeyboardInterrupt:
        with _no_sigint():
            state["status"] = "interrupted"
            state["partial"] = True
            save_params()
            _write_report_safe(rd, state, cfg, None, [])
        raise RunInterrupted(
            f"interrupted during '{state['stage']}'; {rd.path} holds a partial run "
            "(params.json: partial: true); rerun with --resume or --force"
        ) from None
    except BaseException as err:
        with _no_sigint():
            state["status"] = "failed"
            state["partial"] = True
            state["error"] = (
                f"{type(err).__name__}: {err}".splitlines()[0] if str(err) else type(err).__name__
            )
            try:
                save_params()
            except Exception:  # the original error matters more than the bookkeeping
                pass
        raise


def _material_complete(cfg: RunConfig) -> bool:
    """True when the config's ``material:`` block names a class and all of its parameters."""
    from motionphysics.materials.catalog import MATERIALS, normalise_class

    m = cfg.material
    if m.class_ is None or m.density is None:
        return False
    given = m.overrides()
    mc = MATERIALS[normalise_class(m.class_, field="material.class")]
    return all(p.name in given or getattr(p, "default", None) is not None for p in mc.params)


def _material_record(
    material, sim_values: dict[str, float], sim_ctx: dict[str, Any]
) -> dict[str, Any]:
    from motionphysics.materials.catalog import class_id

    return {
        "class": material.cls,
        "class_id": int(class_id(material.cls)),
        "density": float(material.density),
        "params": {k: float(v) for k, v in material.values.items()},
        "units": {k: UNITS[k] for k in ("density", *material.values)},
        "sim": dict(sim_values),
        "sim_context": sim_ctx,
    }


def _check_prior_available(cfg: RunConfig) -> None:
    """Fail fast (exit 2) when the requested prior or the optimiser is not in this build."""
    import importlib.util

    prior = cfg.optimize.prior
    try:
        have_prior = importlib.util.find_spec(f"motionphysics.priors.{prior}") is not None
    except ImportError:  # no motionphysics.priors package in this build at all
        have_prior = False
    have_runner = False
    try:
        from motionphysics import optimize as _opt

        have_runner = hasattr(_opt, "run_prior_optimisation")
    except ImportError:
        have_runner = False
    if not (have_prior and have_runner):
        raise UserInputError(
            f"optimize.prior: '{prior}' is not available in this build; use --prior none "
            "(forward simulation from the estimated material)"
        )


def _optimise(cfg, sim_scene, material, camera, rd, resume: bool, stage_handle) -> dict[str, Any]:
    """The plug-in point: ``motionphysics.optimize.run_prior_optimisation``.

    Expected to return ``{"material": MaterialParams, "sim": {name: float},
    "history": [record, ...], "stop_reason": str}`` and to write ``log.jsonl`` and
    ``checkpoint.pt`` in ``rd.path``.
    """
    from motionphysics.optimize import run_prior_optimisation

    return run_prior_optimisation(
        cfg=cfg,
        sim_scene=sim_scene,
        material=material,
        camera=camera,
        run_dir=rd.path,
        resume=resume,
        on_iteration=stage_handle.advance,
    )


def simulate_forward(sim_scene, cfg: RunConfig, material, sim_values, device, frames: int, st):
    """Forward simulation of ``frames`` frames (shared by ``run``/``simulate`` and ``fit``).

    Returns x [T, P, 3] m, F [T, P, 3, 3] and v [T, P, 3] m/s, float32 numpy (T = frames,
    frame 0 = the initial state).
    """
    from motionphysics.sim import build_simulation

    sim = build_simulation(sim_scene, cfg, {"class": material.cls, **sim_values}, device)
    st.note(f"simulate ({sim.substeps} substeps/frame)")
    ro = sim.rollout
    check = ro.check

    def check_and_count(state, frame):  # called once per simulated frame
        check(state, frame)
        st.advance()

    ro.check = check_and_count
    st.advance()  # frame 0 is the initial state
    xs, Fs, vs = sim.run(frames, return_velocities=True)
    xs = np.asarray(_np(xs), dtype=np.float32)
    Fs = np.asarray(_np(Fs), dtype=np.float32)
    vs = np.asarray(_np(vs), dtype=np.float32)
    if not (np.isfinite(xs).all() and np.isfinite(Fs).all()):
        raise SimulationError(
            "the simulation produced non-finite positions or deformation "
            "gradients; lower sim.frame_dt or use more substeps"
        )
    return xs, Fs, vs, int(sim.substeps)


def render_video(
    rd, sim_scene, xs, Fs, camera, background, ground, cfg: RunConfig, st
) -> np.ndarray:
    """Render every frame (no autograd) and write video.mp4; returns frames [T, H, W, 3] uint8."""
    import torch

    from motionphysics.io.video import write_video

    out = []
    with torch.no_grad():
        for i in range(xs.shape[0]):
            rgb = render_view(
                sim_scene,
                torch.from_numpy(xs[i]),
                torch.from_numpy(Fs[i]),
                camera,
                background,
                ground,
            )
            out.append((np.clip(_np(rgb), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
            st.advance()
    video = np.stack(out)
    with rd.writing("video.mp4") as tmp:
        write_video(video, tmp, _fps(cfg.sim.frame_dt))
    return video


def write_run_trajectory(
    rd, sim_scene, xs, Fs, vs, cfg: RunConfig, material
) -> dict[str, np.ndarray]:
    """Write ``trajectory.npz`` of the run directory (DESIGN.md: x, t, plus F, v, masses,
    volumes and what the viewer and metrics need); returns it as read back."""
    from motionphysics.io.rundir import read_trajectory, write_trajectory

    frames = xs.shape[0]
    volumes = np.asarray(_np(sim_scene.volumes), dtype=np.float64)
    mass = volumes * float(material.density)
    write_trajectory(
        rd.file("trajectory.npz"),
        x=xs,
        t=np.arange(frames, dtype=np.float64) * cfg.sim.frame_dt,
        F=Fs,
        v=vs,
        mass=mass.astype(np.float32),
        volume=volumes.astype(np.float32),
        gravity=np.asarray(cfg.sim.gravity, dtype=np.float32),
        n_visible=np.int64(xs.shape[1] - int(getattr(sim_scene, "n_interior", 0))),
        splat_parent=_np(sim_scene.splat_parent).astype(np.int64),
        splat_offset=_np(sim_scene.splat_offset).astype(np.float32),
        domain_lo=_np(sim_scene.domain_lo).astype(np.float32),
        domain_hi=_np(sim_scene.domain_hi).astype(np.float32),
        dx=np.float32(sim_scene.dx),
        frame_dt=np.float32(cfg.sim.frame_dt),
    )
    return read_trajectory(rd.path / "trajectory.npz")


def write_metrics(rd, traj: dict[str, np.ndarray]) -> dict[str, Any]:
    """Physical diagnostics of ``traj`` -> ``metrics.json`` (flat keys; see metrics.physical)."""
    from motionphysics.metrics.physical import physical_metrics

    metrics = {"schema": "motionphysics.metrics/1", **physical_metrics(traj)}
    rd.write_json("metrics.json", metrics)
    return metrics


def _write_png(rd, name: str, img: np.ndarray) -> None:
    """Write an RGB uint8 image [H, W, 3] as PNG atomically."""
    from PIL import Image

    with rd.writing(name) as tmp:
        Image.fromarray(img).save(tmp, format="PNG")


def _object_row_col(frame0: np.ndarray, background) -> tuple[int, int]:
    """Pixel row and column through the middle of the object in frame 0 (not background)."""
    bg = np.asarray(background, dtype=np.float32) * 255.0
    diff = np.abs(frame0.astype(np.float32) - bg).sum(-1) > 24
    if not diff.any():
        return frame0.shape[0] // 2, frame0.shape[1] // 2
    rows, cols = np.nonzero(diff)
    return int(np.median(rows)), int(np.median(cols))


def _write_plots(rd, video: np.ndarray, traj, metrics, cfg: RunConfig, state) -> list[str]:
    from motionphysics.io.plots import plot_loss, plot_params, plot_series, space_time_slice

    plots = []
    row, col = _object_row_col(video[0], cfg.camera.background)
    space_time_slice(
        video,
        rd.file("plots/slice_row.png"),
        axis="row",
        index=row,
        frame_dt=cfg.sim.frame_dt,
        title=f"space-time slice, pixel row {row}",
    )
    space_time_slice(
        video,
        rd.file("plots/slice_col.png"),
        axis="col",
        index=col,
        frame_dt=cfg.sim.frame_dt,
        title=f"space-time slice, pixel column {col}",
    )
    plots += ["plots/slice_row.png", "plots/slice_col.png"]
    t = traj["t"]
    plot_series(
        {
            "kinetic": metrics["kinetic_energy"],
            "potential (rel. frame 0)": metrics["potential_energy"],
            "total": metrics["total_energy"],
        },
        t,
        rd.file("plots/energy.png"),
        ylabel="energy [J]",
        title="energy",
    )
    plot_series(
        {
            "height / initial": np.asarray(metrics["height"])
            / max(metrics["initial_height"], 1e-9),
            "spread / initial": np.asarray(metrics["spread"]) / max(metrics["spread"][0], 1e-9),
        },
        t,
        rd.file("plots/shape.png"),
        ylabel="ratio",
        title="height and spread",
    )
    plots += ["plots/energy.png", "plots/shape.png"]
    if "volume_ratio" in metrics:
        vr = metrics["volume_ratio"]
        plot_series(
            {"mean det F": vr["mean"], "min": vr["min"], "max": vr["max"]},
            t,
            rd.file("plots/volume.png"),
            ylabel="det F",
            title="volume ratio",
        )
        plots.append("plots/volume.png")
    history = state.get("history") or []
    if history:
        try:
            plot_loss(history, rd.file("plots/loss.png"))
            plots.append("plots/loss.png")
        except ValueError:
            pass
        try:
            from motionphysics.materials.catalog import spec

            ranges = {
                n: (spec(state["class"], n).low, spec(state["class"], n).high)
                for n in state["params"]
            }
            plot_params(history, ranges, rd.file("plots/params.png"))
            plots.append("plots/params.png")
        except ValueError:
            pass
    plots.insert(0, "plots/reference.png")
    return plots


def _write_report_safe(rd, state, cfg: RunConfig, metrics, plots) -> None:
    from motionphysics.io.report import write_report

    write_report(
        rd,
        state,
        prompt=cfg.prompt,
        timings=state.get("timings"),
        metrics=metrics,
        video="video.mp4",
        plots=plots,
        title="motionphysics run",
    )


# --------------------------------------------------------------------------------------
# summary
# --------------------------------------------------------------------------------------
def _fmt(v: float) -> str:
    a = abs(v)
    return f"{v:.4g}" if (a == 0 or 1e-3 <= a < 1e5) else f"{v:.3e}"


def summary_text(result: RunResult) -> str:
    """The final summary a command prints: material, parameters, where the video is, timings."""
    p = result.params
    lines = [f"prompt:    {p.get('prompt', '')}"]
    prov = p.get("provenance") or {}
    lines.append(f"material:  {p.get('class')} (from {prov.get('backend', '?')})")
    sim = p.get("sim") or {}
    units = p.get("units") or {}
    for name, value in {"density": p.get("density"), **(p.get("params") or {})}.items():
        s = f"  {name:<10} {_fmt(float(value)):>12} {units.get(name, ''):<6}"
        if name in sim:
            s += f"  (simulation: {_fmt(float(sim[name]))})"
        src = (prov.get("sources") or {}).get(name)
        if src:
            s += f"  [{src}]"
        lines.append(s)
    for c in prov.get("clamps") or []:
        lines.append(
            f"  clamped {c['field']}: {_fmt(float(c['original']))} -> {_fmt(float(c['clamped']))}"
        )
    m = result.metrics or {}
    if m:
        lines.append(
            f"motion:    final height/initial {m.get('final_height_ratio', float('nan')):.3f}, "
            f"spread ratio {m.get('spread_ratio', float('nan')):.3f}, "
            f"max displacement {m.get('max_displacement', float('nan')):.3f} m"
        )
    lines.append(f"video:     {result.run_dir / 'video.mp4'}")
    lines.append(f"report:    {result.run_dir / 'report.html'}")
    lines.append("timings:")
    total = 0.0
    for k, v in result.timings.items():
        lines.append(f"  {k:<18} {v:8.2f} s")
        total += v
    lines.append(f"  {'total':<18} {total:8.2f} s")
    return "\n".join(lines)


def print_summary(result: RunResult, stream=None) -> None:
    print(summary_text(result), file=stream or sys.stdout)
