"""The one assembly behind every command: a :class:`~motionphysics.config.RunConfig`
(plus a device and whether gradients are needed) -> the parts a run is made of.

:func:`assemble` loads and prepares the scene, resolves the camera (auto-framing) and
the ground floor, resolves the material with its provenance (config ``material:``
block > ``--params`` file > init backend estimate > range centre), and resolves the
simulation context **once**: the map context of :mod:`motionphysics.materials.simmap`
(``dt = frame_dt / 512`` under ``substeps: auto``, ``frame_dt / n`` for a fixed ``n``),
the simulation values and the substep count. ``run``, ``simulate``, ``fit``, the
system-identification cases and the prior-driven refinement all build their
simulation here, so the same config and parameters give the same trajectory, bit for
bit, whichever command runs it (tests/test_assembly.py).

The physical -> simulation map is evaluated by one function, :func:`sim_values`, in
torch float64 for every caller (the forward-only commands and the differentiable
optimisation alike); a Python-float path beside it would round differently.

:class:`BridgeSimulator` and :class:`SplatRenderer` are the adapters the optimisation
loop (:mod:`motionphysics.optimize`) consumes; under ``substeps: auto`` the simulator
re-resolves the substep count from the current parameters before each rollout and
reports a change through the observer (the rollout's CFL check stays in force).

The phases live in their own modules, each re-exported here (``from
motionphysics.assembly import resolve_camera`` keeps working): the scene phase of a
region of a capture (:mod:`motionphysics.assembly_scene`), the material
(:mod:`motionphysics.assembly_material`), the simulation context and the forward rollout
(:mod:`motionphysics.assembly_simulation`), and the camera, the ground and the frames
(:mod:`motionphysics.assembly_camera`). This module keeps the objects of a scene of
several, the adapters the optimisation loop consumes and :func:`assemble` itself.

This module builds and runs components; it writes no files (the run directory is
:mod:`motionphysics.io.writer`'s) and must not import ``motionphysics.pipeline``,
``motionphysics.commands`` or ``motionphysics.optimize``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from motionphysics.assembly_camera import (  # noqa: F401 - the camera phase, re-exported
    GROUND_FRICTION,
    _fit_radius,
    _ground_height,
    _lowest,
    _object_box,
    _up,
    default_ground,
    ground_splats,
    render_frames,
    render_view,
    resolve_camera,
)
from motionphysics.assembly_material import (  # noqa: F401 - the material phase, re-exported
    _provenance,
    estimate_material,
    material_complete,
    resolve_material,
    warn,
)
from motionphysics.assembly_simulation import (  # noqa: F401 - the simulation phase, re-exported
    SimResolution,
    _budget,
    _floats,
    _material_sim,
    _pinned,
    map_context,
    resolve_simulation,
    resolve_substeps,
    scene_scales,
    sim_values,
    simulate_forward,
)
from motionphysics.config import (
    MaterialConfig,
    ObjectConfig,
    RunConfig,
    SceneConfig,
)
from motionphysics.errors import UserInputError
from motionphysics.events import NullObserver, Observer

__all__ = [
    "Assembly",
    "BridgeSimulator",
    "ObjectPart",
    "ObjectsSimulator",
    "SceneMaterial",
    "SceneResolution",
    "SimResolution",
    "SplatRenderer",
    "assemble",
    "estimate_material",
    "ground_splats",
    "map_context",
    "material_complete",
    "render_frames",
    "render_view",
    "resolve_camera",
    "resolve_material",
    "resolve_simulation",
    "resolve_substeps",
    "sim_values",
    "simulate_forward",
]


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


@contextmanager
def _null_stage(name: str, total: int | None = None) -> Iterator[Any]:
    yield _NullHandle()


class _NullHandle:
    def advance(self, n: int = 1) -> None:
        pass

    def note(self, text: str) -> None:
        pass

    def set_total(self, total: int) -> None:
        pass


# --------------------------------------------------------------------------------------
# several objects
# --------------------------------------------------------------------------------------
SIM_FILL = {"n": 1.0}
"""Value a per-particle simulation array takes on the particles of an object whose class
has no such parameter (never read by that class's constitutive model; 0 otherwise)."""


@dataclass(frozen=True)
class ObjectPart:
    """One object of a scene of several: its resolved material and where it came from."""

    name: str
    material: Any
    """catalog.MaterialParams of this object."""
    resolution: SimResolution
    """Map context (this object's density and size), simulation values, substeps."""
    provenance: dict[str, Any]
    initial_velocity: tuple[float, float, float]
    """m/s (the object's ``initial_velocity`` or ``sim.initial_velocity``)."""
    count: int
    """Particles of this object."""


@dataclass(frozen=True)
class SceneMaterial:
    """The materials of several objects as the simulator sees them: per particle.

    ``class_ids [P]`` int32, ``density [P]`` kg/m^3 (so masses are ``density x volume``
    as for one object), ``object_id [P]`` int64; ``objects`` holds each object's
    :class:`ObjectPart`."""

    objects: tuple[ObjectPart, ...]
    object_id: np.ndarray

    @property
    def cls(self) -> str:
        """The classes, comma-joined in object order (display only)."""
        return ",".join(o.material.cls for o in self.objects)

    @property
    def class_ids(self) -> np.ndarray:
        from motionphysics.materials.catalog import class_id

        ids = np.array([int(class_id(o.material.cls)) for o in self.objects], dtype=np.int32)
        return ids[self.object_id]

    @property
    def density(self) -> np.ndarray:
        d = np.array([float(o.material.density) for o in self.objects], dtype=np.float64)
        return d[self.object_id]

    @property
    def values(self) -> dict[str, np.ndarray]:
        """Physical parameters per particle [P] (the union of the objects' names)."""
        return _per_particle_union([o.material.values for o in self.objects], self.object_id)


def _per_particle_union(dicts: list[Mapping[str, Any]], object_id) -> dict[str, Any]:
    """{name: [P]} from one {name: value} per object (``SIM_FILL`` where an object lacks
    ``name``); torch tensors stay differentiable (:func:`sim.per_object`)."""
    from motionphysics.sim.model import per_object

    names = list(dict.fromkeys(k for d in dicts for k in d))
    out = {}
    for name in names:
        vals = [d.get(name, SIM_FILL.get(name, 0.0)) for d in dicts]
        out[name] = per_object(np.asarray(object_id), vals)
    return out


@dataclass(frozen=True)
class SceneResolution:
    """:class:`SimResolution` of a scene of several objects (per-particle values)."""

    values: dict[str, Any]
    """Simulation values per particle [P] float32 (density included)."""
    class_ids: np.ndarray
    substeps: int
    frame_dt: float
    grid_dims: tuple[int, int, int]
    auto: bool
    dx: float
    objects: tuple[SimResolution, ...]
    context: Any = None

    @property
    def dt(self) -> float:
        return self.frame_dt / self.substeps

    def record(self) -> dict[str, Any]:
        """The ``sim_context`` block of ``params.json`` (each object's map: ``objects``)."""
        return {
            "dx": float(self.dx),
            "dt": self.frame_dt / self.substeps,
            "dt_map": float(self.objects[0].context.dt),
            "substeps": int(self.substeps),
            "substeps_mode": "auto" if self.auto else "fixed",
            "frame_dt": float(self.frame_dt),
            "length": max(float(o.context.length) for o in self.objects),
            "grid_dims": [int(v) for v in self.grid_dims],
        }


class _ObjectView:
    """The particles of one object with the scene's grid (what :func:`map_context` reads)."""

    def __init__(self, sim_scene, mask: np.ndarray):
        self.particles = _np(sim_scene.particles)[mask]
        self.volumes = _np(sim_scene.volumes)[mask]
        self.wall_lo = getattr(sim_scene, "wall_lo", None)
        self.wall_hi = getattr(sim_scene, "wall_hi", None)
        self.dx = float(sim_scene.dx)
        self.grid_dims = tuple(int(v) for v in sim_scene.grid_dims)


def object_config(cfg: RunConfig, ocfg) -> RunConfig:
    """The one-object config of object ``ocfg`` (its scene keys, material, velocity).

    Built from the typed models (``model_copy``): the keys the person set stay set, and
    nothing is re-read from plain data (see :func:`_typed`)."""
    # (its part is already selected: the one-object config resolves its material only)
    keys = (ocfg.model_fields_set & set(SceneConfig.model_fields)) - {"split", "part"}
    scene = SceneConfig.model_construct(
        _fields_set=set(keys), **{k: getattr(ocfg, k) for k in keys}
    )
    sim = cfg.sim
    if ocfg.initial_velocity is not None:
        sim = sim.model_copy(update={"initial_velocity": ocfg.initial_velocity})
    return cfg.model_copy(
        update={"objects": None, "scene": scene, "material": ocfg.material, "sim": sim}
    )


def _material_block(material, where: str) -> MaterialConfig:
    """The ``material:`` block recording a resolved material (run.yaml re-runs it)."""
    from pydantic import ValidationError

    try:
        return MaterialConfig.model_validate(material.to_dict())
    except ValidationError as err:  # pragma: no cover - resolved materials are valid
        first = err.errors()[0]
        field = ".".join(str(p) for p in first.get("loc", ()))
        raise UserInputError(f"{where}.{field}: {first.get('msg', 'invalid')}") from None


def _typed(cfg: RunConfig, origin: str) -> RunConfig:
    """``cfg`` (made by ``model_copy``, which runs no validator) checked by the config's
    own cross-field rules. The assembly passes typed configs down and never re-reads one
    from plain data: a ``config_to_dict`` -> ``config_from_dict`` round trip would forget
    which keys the person set (``model_fields_set``) and write defaults in as if given."""
    try:
        cfg._objects_or_scene()
    except ValueError as err:
        raise UserInputError(f"{origin}: {err}") from None
    return cfg


def resolve_scene_simulation(
    cfg: RunConfig, sim_scene, materials: list, names: list[str]
) -> tuple[list[SimResolution], SceneResolution]:
    """Each object's :class:`SimResolution` (its own density and size in the map context)
    and the scene's per-particle :class:`SceneResolution` (substeps: the stiffest
    object's CFL limit under ``auto``)."""
    oid = _np(sim_scene.object_id).astype(np.int64)
    per = []
    ocfgs = list(cfg.object_configs())
    # Objects meet each other: each one's map sees the others' speeds (closing speed).
    own = [
        float(
            np.linalg.norm(
                o.initial_velocity if o.initial_velocity is not None else cfg.sim.initial_velocity
            )
        )
        for o in ocfgs
    ]
    for k, (mat, ocfg) in enumerate(zip(materials, ocfgs, strict=True)):
        others = max([v for j, v in enumerate(own) if j != k], default=0.0)
        per.append(
            resolve_simulation(
                mat,
                object_config(cfg, ocfg),
                _ObjectView(sim_scene, oid == k),
                closing_speed=others,
            )
        )
    from motionphysics.materials.catalog import class_id

    ids = np.array([int(class_id(m.cls)) for m in materials], dtype=np.int32)[oid]
    values = _per_particle_union([r.values for r in per], oid)
    substeps = resolve_substeps(cfg, ids, values, float(sim_scene.dx))
    return per, SceneResolution(
        values=values,
        class_ids=ids,
        substeps=substeps,
        frame_dt=float(cfg.sim.frame_dt),
        grid_dims=tuple(int(v) for v in sim_scene.grid_dims),
        auto=cfg.sim.substeps == "auto",
        dx=float(sim_scene.dx),
        objects=tuple(per),
    )


def estimate_objects(
    prompt: str, names: list[str], image, backend: str, announce: bool = False
) -> list[dict[str, Any]]:
    """Per-object estimates from one prompt (``init.estimate_objects``), as
    :func:`estimate_material` records them, in ``names`` order."""
    from motionphysics.init import EstimateOptions
    from motionphysics.init.estimate import estimate_objects as _estimate

    ests = _estimate(
        prompt, names, image=image, backend=backend, options=EstimateOptions(announce=announce)
    )
    return [
        {
            "class": est.cls,
            "density": float(est.density),
            "params": {k: float(v) for k, v in est.values.items()},
            "backend": est.backend,
            "raw": est.raw_answer,
            "clamps": [c.to_dict() for c in est.clamped],
            "estimate": est.to_dict(),
        }
        for est in ests
    ]


# --------------------------------------------------------------------------------------
# --------------------------------------------------------------------------------------
# the adapters the optimisation loop consumes
# --------------------------------------------------------------------------------------
class BridgeSimulator:
    """The MPM torch bridge behind the optimiser's :class:`~motionphysics.optimize.Simulator`.

    Under ``substeps: auto`` each rollout first re-resolves the substep count from the
    simulation values it is given (:func:`resolve_substeps`, the same function the
    forward commands use) and rebuilds the rollout when it changes, reporting the
    change through ``observer.message`` and in :attr:`changes`.
    """

    def __init__(self, simulation, num_frames: int, *, cfg=None, cls=None, observer=None):
        self.simulation = simulation
        self.num_particles = int(simulation.model.particle_count)
        self.num_frames = int(num_frames)
        self._cfg = cfg
        self._cls = cls
        self._observer = observer or NullObserver()
        self.changes: list[tuple[int, int]] = []
        """(old, new) substep counts, in order, each time the count was re-resolved."""

    @property
    def substeps(self) -> int:
        return int(self.simulation.substeps)

    def _retime(self, sim_params) -> None:
        if self._cfg is None or self._cfg.sim.substeps != "auto":
            return
        n = resolve_substeps(self._cfg, self._cls, sim_params, float(self.simulation.model.dx))
        old = int(self.simulation.substeps)
        if n != old:
            self.simulation.substeps = n
            self.simulation._rollout = None  # the next rollout uses the new count
            self.changes.append((old, n))
            self._observer.message(
                "info",
                f"substeps re-resolved for the current parameters: {old} -> {n} per frame "
                "(sim.substeps: auto, CFL limit)",
            )

    def simulate(self, sim_params, initial_velocity, frames, grad_mode, window):
        from motionphysics.sim.bridge import simulate
        from motionphysics.sim.model import PARAM_NAMES

        self._retime(sim_params)
        params = {k: v for k, v in sim_params.items() if k in PARAM_NAMES}
        return simulate(
            self.simulation,
            params,
            frames=frames,
            initial_velocity=initial_velocity,
            grad_mode=grad_mode,
            window=window,
        )


class SplatRenderer:
    """Differentiable frames of the run camera (splats follow the particles, plus the ground).

    ``(xs [S,P,3], Fs [S,P,3,3]) -> rgb [S,H,W,3]`` float32 in [0, 1].
    """

    def __init__(self, sim_scene, camera, background, ground):
        self.sim_scene = sim_scene
        self.camera = camera
        self.background = background
        self.ground = ground

    def __call__(self, xs, Fs):
        import torch

        return torch.stack(
            [
                render_view(self.sim_scene, xs[i], Fs[i], self.camera, self.background, self.ground)
                for i in range(xs.shape[0])
            ]
        )


# --------------------------------------------------------------------------------------
# the assembly
# --------------------------------------------------------------------------------------
@dataclass
class Assembly:
    """Everything a command needs, built once from a config (see :func:`assemble`)."""

    cfg: RunConfig
    """The config with the camera resolved and the ``material:`` block filled in (what
    ``run.yaml`` records; ``sim.substeps`` keeps the config's value, ``auto`` included)."""
    device: str
    needs_grad: bool
    sim_scene: Any
    """scene.prepare.SimScene: splats, particles [P,3] m, volumes [P] m^3, grid."""
    camera: Any
    camera_note: dict[str, Any]
    background: tuple[float, float, float]
    ground: dict[str, Any] | None
    """Ground splats (render only) or None."""
    material: Any
    """The resolved physical material (catalog.MaterialParams)."""
    provenance: dict[str, Any]
    """Where each field came from: backend, sources, clamps, estimate, params file."""
    resolution: SimResolution
    observer: Observer = field(default_factory=NullObserver)
    reference_image: np.ndarray | None = None
    """uint8 [H, W, 3] rest-state render (when one was made)."""
    objects: tuple[ObjectPart, ...] | None = None
    """Several objects (``objects:``): each one's material, resolution and provenance;
    ``material`` is then their :class:`SceneMaterial` and ``resolution`` a
    :class:`SceneResolution`. None: one object."""
    last_rollout: Any = None
    """The last :meth:`simulate`'s full rollout result (``active`` [T, P], ``wall_hits``)."""
    scene_notes: dict[str, str] = field(default_factory=dict)
    """Lines for the ``scene`` block of params.json and the summary: ``ground`` (the
    default ground, when the config left ``boundary_conditions`` out) and ``fill`` (why
    ``fill: true`` gave no interior particle)."""
    _simulation: Any = field(default=None, repr=False)

    @property
    def initial_velocity(self) -> np.ndarray | None:
        """[P, 3] m/s of a scene of several objects (each its own), else None."""
        if self.objects is None:
            return None
        v = np.array([o.initial_velocity for o in self.objects], dtype=np.float32)
        return v[_np(self.sim_scene.object_id).astype(np.int64)]

    # -- the simulation ----------------------------------------------------------------
    @property
    def num_particles(self) -> int:
        return int(_np(self.sim_scene.particles).shape[0])

    @property
    def simulation(self):
        """The :class:`~motionphysics.sim.Simulation` of the resolved material (built once)."""
        if self._simulation is None:
            from motionphysics.sim import build_simulation

            self._simulation = build_simulation(
                self.sim_scene,
                _pinned(self.cfg, self.resolution.substeps),
                _material_sim(self.material, self.resolution.values),
                self.device,
                requires_grad=self.needs_grad,
            )
            if self.objects is not None:
                self._simulation.set_initial_velocity(self.initial_velocity)
        return self._simulation

    def with_material(self, material) -> Assembly:
        """The same scene and camera with another material (resolved the same way);
        several objects: a list of MaterialParams, one per object."""
        if self.objects is not None:
            return self.with_materials(material)
        res = resolve_simulation(material, self.cfg, self.sim_scene)
        return replace(self, material=material, resolution=res, _simulation=None)

    def reframe(self, cfg_in: RunConfig, xs) -> Assembly:
        """The same run with the automatic camera framing the whole trajectory ``xs``
        [T, P, 3] (unchanged when ``cfg_in``'s camera is explicit)."""
        from motionphysics.render.camera import camera_from_config

        cfg_cam, note = resolve_camera(cfg_in, self.sim_scene, xs=xs)
        if note.get("framing") == "config":
            return self
        cfg = self.cfg.model_copy(update={"camera": cfg_cam.camera})
        camera = camera_from_config(cfg.camera, self.sim_scene.source_to_world)
        return replace(self, cfg=cfg, camera=camera, camera_note=note)

    def with_materials(self, materials) -> Assembly:
        """Several objects: new MaterialParams per object (a list or a SceneMaterial)."""
        if isinstance(materials, SceneMaterial):
            materials = [o.material for o in materials.objects]
        names = [o.name for o in self.objects]
        per, res = resolve_scene_simulation(self.cfg, self.sim_scene, list(materials), names)
        objects = tuple(
            replace(o, material=m, resolution=r)
            for o, m, r in zip(self.objects, materials, per, strict=True)
        )
        mat = SceneMaterial(objects, _np(self.sim_scene.object_id).astype(np.int64))
        return replace(self, material=mat, resolution=res, objects=objects, _simulation=None)

    def to_sim(self, physical: Mapping[str, Any]) -> dict[str, Any]:
        """Physical values (density included; tensors or floats) -> simulation values
        (differentiable; :func:`sim_values` in the resolved map context)."""
        return sim_values(physical, self.material.cls, self.resolution.context)

    def to_sim_objects(self, physicals: list[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """Several objects: one physical dict per object (density included; tensors or
        floats) -> one simulation dict each, in that object's map context
        (differentiable; what :class:`ObjectsSimulator` takes)."""
        if self.objects is None:
            raise RuntimeError("to_sim_objects: this assembly has one object (use to_sim)")
        return [
            sim_values(p, o.material.cls, o.resolution.context)
            for p, o in zip(physicals, self.objects, strict=True)
        ]

    def simulate(self, frames: int | None = None, st=None, *, material=None, cfg=None):
        """Forward rollout -> (x [T,P,3], F [T,P,3,3], v [T,P,3] float32, substeps).

        ``material`` / ``cfg`` (e.g. a fitted initial velocity) replace the assembly's;
        the simulation context is resolved again for them by the same functions.
        """
        cfg = cfg or self.cfg
        if self.objects is not None and material is not None:
            return self.with_materials(material).simulate(frames, st, cfg=cfg)
        mat = material or self.material
        res = self.resolution if material is None else resolve_simulation(mat, cfg, self.sim_scene)
        keep: dict[str, Any] = {}
        out = simulate_forward(
            self.sim_scene,
            cfg,
            mat,
            res.values,
            self.device,
            int(frames or cfg.sim.frames),
            st or _NullHandle(),
            self.observer,
            initial_velocity=self.initial_velocity,
            keep=keep,
        )
        self.last_rollout = keep.get("last")
        return out

    def render(self, xs, Fs, on_frame=None) -> np.ndarray:
        """uint8 frames [T, H, W, 3] of the run camera for states x [T,P,3], F [T,P,3,3]."""
        return render_frames(
            self.sim_scene, xs, Fs, self.camera, self.background, self.ground, on_frame
        )

    # -- adapters for the optimisation loop --------------------------------------------
    def simulator(self, num_frames: int | None = None, *, per_object: bool = False):
        """Differentiable simulator (needs ``needs_grad=True``); several objects:
        ``per_object=True`` gives the :class:`ObjectsSimulator` (one parameter vector per
        object)."""
        if not self.needs_grad:
            raise RuntimeError("assemble(..., needs_grad=True) is required for a simulator")
        if self.objects is not None:
            if not per_object:
                raise ValueError(
                    "an assembly of several objects has one parameter vector per object: "
                    "simulator(per_object=True) (optimize.objects builds its problem)"
                )
            return ObjectsSimulator(self, int(num_frames or self.cfg.sim.frames))
        return BridgeSimulator(
            self.simulation,
            int(num_frames or self.cfg.sim.frames),
            cfg=self.cfg,
            cls=self.material.cls,
            observer=self.observer,
        )

    def renderer(self) -> SplatRenderer:
        """Differentiable renderer of the run camera."""
        return SplatRenderer(self.sim_scene, self.camera, self.background, self.ground)


def _render_reference(sim_scene, camera, background, ground) -> np.ndarray:
    import torch

    P = int(_np(sim_scene.particles).shape[0])
    with torch.no_grad():
        ref = render_view(
            sim_scene, sim_scene.particles, torch.eye(3).expand(P, 3, 3), camera, background, ground
        )
    return (np.clip(_np(ref), 0, 1) * 255 + 0.5).astype(np.uint8)


def assemble(
    cfg: RunConfig,
    device: str = "cpu",
    needs_grad: bool = False,
    *,
    init_backend: str = "kb",
    params_file: Mapping[str, Any] | None = None,
    estimate: bool = True,
    reference_image: bool = True,
    stage: Callable[..., Any] | None = None,
    observer: Observer | None = None,
    announce: bool = False,
    config_origin: str = "<config>",
    on_scene: Callable[[Any], None] | None = None,
    on_camera: Callable[[RunConfig, dict[str, Any], np.ndarray | None], None] | None = None,
) -> Assembly:
    """Build the parts of a run from ``cfg``.

    Stages (each run inside ``stage(name)``, a context manager factory such as
    :meth:`motionphysics.io.writer.RunWriter.stage`): ``load scene``, ``reference
    render``, ``estimate material`` (only when the material is incomplete and
    ``estimate``), ``resolve material``.

    ``params_file``: the mapping of :func:`motionphysics.runconfig.read_params_file`.
    ``estimate=False``: the material comes from the config (and ``params_file``)
    alone; a missing class is a user error (``fit``). ``reference_image=False`` skips
    the rest-state render unless the estimate needs it. ``on_scene(sim_scene)`` and
    ``on_camera(cfg, note, image)`` are called as soon as those exist (the writer
    records them).
    """
    from motionphysics.init import INIT_BACKENDS

    INIT_BACKENDS.check(init_backend)
    stage = stage or _null_stage
    observer = observer or NullObserver()
    if cfg.objects is None and cfg.scene.split is not None:
        cfg = split_config(cfg, config_origin)
    if cfg.objects is not None:
        return _assemble_objects(
            cfg,
            device,
            needs_grad,
            init_backend=init_backend,
            params_file=params_file,
            estimate=estimate,
            reference_image=reference_image,
            stage=stage,
            observer=observer,
            announce=announce,
            config_origin=config_origin,
            on_scene=on_scene,
            on_camera=on_camera,
        )
    with stage("load scene"):
        from motionphysics.scene import load_scene
        from motionphysics.scene.prepare import prepare

        scene = load_scene(cfg.scene.source, shade=cfg.scene.shade)
        capture = _capture_warnings(scene, cfg.scene, observer)
        cfg, ground_note = default_ground(cfg, *_lowest(scene, cfg.scene))
        # The fitted domain leaves room for the motion the config implies (initial
        # velocity, gravity, forces). The class-based spread allowance of prepare() is not
        # used: at a fixed sim.grid it widened a sand column's domain 3x (dx 0.031 ->
        # 0.085 m, five cells across the column), which turned the heap into a sheet.
        sim_scene = prepare(
            scene,
            cfg.scene,
            cfg.sim,
            list(cfg.boundary_conditions),
            forces=list(cfg.forces),
        )
        observer.message(
            "info",
            f"scene: {sim_scene.splats.num} splats, {int(_np(sim_scene.particles).shape[0])} "
            "particles",
        )
        if on_scene is not None:
            on_scene(sim_scene)

    need_estimate = estimate and params_file is None and not material_complete(cfg)
    ref_np = None
    with stage("reference render"):
        from motionphysics.render.camera import camera_from_config

        cfg, cam_note = resolve_camera(cfg, sim_scene)
        camera = camera_from_config(cfg.camera, sim_scene.source_to_world)
        background = tuple(float(v) for v in cfg.camera.background)
        ground = ground_splats(cfg, sim_scene)
        if reference_image or need_estimate:
            ref_np = _render_reference(sim_scene, camera, background, ground)
        if on_camera is not None:
            on_camera(cfg, cam_note, ref_np)

    est = None
    if need_estimate:
        with stage("estimate material"):
            est = estimate_material(cfg.prompt, ref_np, init_backend, announce=announce)
            observer.message("info", f"estimate ({init_backend}): {est['class']}")
    with stage("resolve material"):
        from motionphysics.materials.simmap import mapped_substitutions

        res = resolve_material(cfg, est, params_file)
        material = res["material"]
        for line in res.get("warnings", []):
            warn(line, observer)
        if est is not None:
            for line in (est.get("estimate") or {}).get("warnings", []) or []:
                warn(line, observer)
        from motionphysics.scene.prepare import widen_for_spread

        sim_scene, domain_note = widen_for_spread(sim_scene, material.cls, cfg.sim, cfg.scene)
        if domain_note:
            capture = [*capture, domain_note]  # (kept as the scene's `domain` note)
        resolution = resolve_simulation(material, cfg, sim_scene)
        for line in resolution.notes:
            warn(line, observer)
        for note in (
            own_weight_note(material, cfg, _np(sim_scene.particles)),
            ooze_note(material, cfg, _np(sim_scene.particles)),
        ):
            if note:
                warn(note, observer)
        provenance = {
            **_provenance(est, res, params_file),
            "clamps": res["clamps"]
            + [
                c.to_dict()
                for c in mapped_substitutions(material, resolution.values, ctx=resolution.context)
            ],
            "warnings": list(res.get("warnings", [])),
            "range_notes": list(res.get("range_notes", [])),
        }
        # The config records the material that is simulated (before any optimisation),
        # so re-running run.yaml reproduces the run.
        cfg = cfg.model_copy(update={"material": _material_block(material, "material")})
    return Assembly(
        cfg=cfg,
        device=device,
        needs_grad=needs_grad,
        sim_scene=sim_scene,
        camera=camera,
        camera_note=cam_note,
        background=background,
        ground=ground,
        material=material,
        provenance=provenance,
        resolution=resolution,
        observer=observer,
        reference_image=ref_np,
        scene_notes=_scene_notes(ground_note, sim_scene, observer, capture),
    )


OWN_WEIGHT_SLUMP = 1.0
"""An elastic body whose own weight strains it by this much (density x g x height / E)
slumps under it whatever the simulator does: the run says so, with the size."""


def own_weight_note(material, cfg: RunConfig, particles) -> str | None:
    """One line when the material, at the object's size, slumps under its own weight: a
    1 m builtin jelly cube (E 5 kPa) strains 2x, sinks to half its height and reads as
    neither a wobble nor a bounce; the same jelly at 10 cm strains 0.2 and wobbles. It is
    the physics of a body that large, which the sentence rarely means."""
    if material.cls not in ("elastic", "foam"):
        return None
    E = float(material.values.get("E", 0.0))
    g = float(np.linalg.norm(np.asarray(cfg.sim.gravity, dtype=np.float64)))
    p = np.asarray(particles, dtype=np.float64)
    if not (E > 0 and g > 0 and len(p)):
        return None
    down = -np.asarray(cfg.sim.gravity, dtype=np.float64) / g
    h = float(np.ptp(p @ down))
    strain = float(material.density) * g * h / E
    if strain < OWN_WEIGHT_SLUMP:
        return None
    return (
        f"material: at this size ({h:.3g} m tall) its own weight strains the {material.cls} "
        f"by {100 * strain:.0f} % (density x g x height / E, E {E:.3g} Pa): a body this "
        "large and this soft slumps under its own weight instead of keeping its shape (the "
        "physics of its size); `scene.scale` makes it smaller (builtins are 1 m unless "
        "scaled), `material: {E: ...}` stiffer"
    )


OOZE_TIME = 0.05
"""A Newtonian fluid oozes over a clip when its viscous time ``mu / (density g h)`` is at
least about this fraction of the clip (the lava example, 300 Pa s at 0.2 m over 1.2 s:
0.05, reads as oozing, adherence 0.88); :data:`OOZE_SHORT` of it or less runs out."""
OOZE_SHORT = 0.01
"""... below this fraction the run says why it does not ooze (a metre of honey: 0.002)."""


def ooze_note(material, cfg: RunConfig, particles) -> str | None:
    """One line when the prompt asks a Newtonian fluid to ooze and, at the object's size,
    its viscous time is far shorter than the clip: a 1 m block of honey (30 Pa s) runs out
    like water within a few frames (``mu / (density g h)`` = 2 ms against a 1.2 s clip);
    the line names the viscosity an ooze over the clip needs."""
    if material.cls != "newtonian":
        return None
    from motionphysics.language.captions import prompt_motion_group

    # (the raw reading: a Newtonian fluid can show "oozes"; assembly does not import
    # priors, whose class-aware reading asked_motion would add nothing here)
    if prompt_motion_group(cfg.prompt)[0] != "oozes":
        return None
    mu = float(material.values.get("mu", 0.0))
    g = float(np.linalg.norm(np.asarray(cfg.sim.gravity, dtype=np.float64)))
    p = np.asarray(particles, dtype=np.float64)
    duration = max(int(cfg.sim.frames) - 1, 1) * float(cfg.sim.frame_dt)
    if not (mu > 0 and g > 0 and len(p)):
        return None
    h = float(np.ptp(p @ (-np.asarray(cfg.sim.gravity, dtype=np.float64) / g)))
    rho_g_h = float(material.density) * g * max(h, 1e-9)
    t_visc = mu / rho_g_h
    if t_visc >= OOZE_SHORT * duration:
        return None
    need = OOZE_TIME * rho_g_h * duration
    return (
        f"material: at this size ({h:.3g} m tall) the fluid's viscous time mu / (density x g "
        f"x height) is {1e3 * t_visc:.3g} ms against the {duration:.3g} s clip: it runs out "
        f"within the first frames rather than oozing; an ooze over the clip needs mu of "
        f"about {need:.2g} Pa s (`material: {{mu: ...}}`) or a smaller object (`scene.scale`)"
    )


def _capture_warnings(scene, scene_cfg, observer, prefix: str = "") -> list[str]:
    """Warn (one line each) what a capture loaded as it is was read as and what to set:
    its header's vertical axis, floaters, its size (:mod:`motionphysics.scene.capture_notes`)."""
    from motionphysics.scene.capture_notes import capture_notes
    from motionphysics.scene.prepare import selected_means

    lines = [prefix + n for n in capture_notes(scene_cfg, selected_means(scene, scene_cfg))]
    for line in lines:
        warn(line, observer)
    return lines


def _scene_notes(
    ground_note: str | None, sim_scene, observer, capture: list[str] | None = None
) -> dict[str, str]:
    """The ``ground`` and ``fill`` lines of a prepared scene (see Assembly.scene_notes);
    a fill that leaves the object hollow is also a warning (its mass is the surface's).
    ``capture``: the warnings about a capture loaded as it is (already given), kept as
    ``capture`` (one line each, joined by newlines)."""
    notes = {}
    domain = [c for c in capture or [] if c.startswith("domain: ")]
    capture = [c for c in capture or [] if not c.startswith("domain: ")]
    if capture:
        notes["capture"] = "\n".join(capture)
    if domain:
        notes["domain"] = domain[0]
        observer.message("info", domain[0])
    if ground_note:
        notes["ground"] = ground_note
        observer.message("info", ground_note)
    from motionphysics.assembly_scene import static_lines

    static, sparse = static_lines(sim_scene)
    if static:
        notes["static"] = static
        observer.message("info", static)
    if sparse:
        notes["static_support"] = sparse
        warn(sparse, observer)
    from motionphysics.assembly_scene import resolution_line

    coarse = resolution_line(sim_scene)
    if coarse:
        notes["resolution"] = coarse
        warn(coarse, observer)
    fill = getattr(sim_scene, "fill_note", None)
    if fill:
        notes["fill"] = fill
        if getattr(sim_scene, "fill_hollow", False):
            warn(fill, observer)
        else:
            observer.message("info", fill)
    return notes


def split_config(cfg: RunConfig, origin: str = "<config>") -> RunConfig:
    """``scene.split`` -> the same config with one ``objects:`` entry per part.

    Each part keeps the scene keys (``split`` + ``part`` select its splats), gets the
    ``material:`` block and a share of ``scene.max_particles`` proportional to its splats;
    names come from ``scene.split_names`` or are ``part<id>``."""
    from motionphysics.scene import load_scene
    from motionphysics.scene.split import part_labels

    sc = cfg.scene
    scene = load_scene(sc.source, shade=sc.shade)
    labels = part_labels(scene, sc.source, sc.split, sc.split_property)
    parts, counts = np.unique(labels, return_counts=True)
    if sc.split_names is not None and len(sc.split_names) != len(parts):
        raise UserInputError(
            f"scene.split_names: {len(sc.split_names)} names for the {len(parts)} parts "
            f"{sc.source} splits into by {sc.split}"
        )
    names = sc.split_names or [f"part{int(p)}" for p in parts]
    from pydantic import ValidationError

    base = {
        k: getattr(sc, k) for k in sc.model_fields_set - {"split_names", "max_particles", "part"}
    }
    total = int(counts.sum())
    objects = []
    for i, (name, p, c) in enumerate(zip(names, parts, counts, strict=True)):
        try:
            objects.append(
                ObjectConfig(
                    **base,
                    name=name,
                    part=int(p),
                    max_particles=max(1, round(sc.max_particles * int(c) / total)),
                    material=cfg.material,
                )
            )
        except ValidationError as err:
            first = err.errors()[0]
            field = ".".join(str(q) for q in first.get("loc", ()))
            raise UserInputError(
                f"{origin}: objects[{i}].{field} (from scene.split): got "
                f"{first.get('input')!r}; {first.get('msg', 'invalid')}"
            ) from None
    new = cfg.model_copy(
        update={"objects": objects, "scene": SceneConfig(), "material": MaterialConfig()}
    )
    return _typed(new, origin)


def _assemble_objects(
    cfg: RunConfig,
    device: str,
    needs_grad: bool,
    *,
    init_backend: str,
    params_file,
    estimate: bool,
    reference_image: bool,
    stage,
    observer,
    announce: bool,
    config_origin: str,
    on_scene,
    on_camera,
) -> Assembly:
    """:func:`assemble` for ``objects:``: each object loaded and prepared with its own scene
    keys onto one grid (:func:`scene.prepare.prepare_objects`), one estimate per object from
    the one prompt (``init.estimate_objects``), each object's material resolved from its
    own ``material:`` block like a single object's."""
    from motionphysics.render.camera import camera_from_config
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare_objects

    if params_file is not None:
        raise UserInputError(
            "--params: a params file holds one material; with objects: give each object's "
            "material: block in the config instead"
        )
    ocfgs = cfg.object_configs()
    names = [o.name for o in ocfgs]
    with stage("load scene"):
        loaded: dict[tuple[str, bool], Any] = {}
        scenes = []
        for i, o in enumerate(ocfgs):
            key = (o.source, o.shade)
            if key not in loaded:
                loaded[key] = load_scene(o.source, shade=o.shade)
            scene = loaded[key]
            if o.split is not None:
                from motionphysics.scene.split import select_part

                scene = select_part(
                    scene, o.source, o.split, o.part, o.split_property, f"objects[{i}].part"
                )
            scenes.append(scene)
        capture = []
        for s, o in zip(scenes, ocfgs, strict=True):
            capture += _capture_warnings(s, o, observer, f"objects: {o.name}: ")
        lows = [_lowest(s, o) for s, o in zip(scenes, ocfgs, strict=True)]
        cfg, ground_note = default_ground(
            cfg,
            min(z for z, _, _ in lows),
            max(size for _, size, _ in lows),
            max(z + h for z, _, h in lows) - min(z for z, _, _ in lows),
        )
        classes = [o.material.class_ for o in ocfgs]
        sim_scene = prepare_objects(
            scenes, ocfgs, cfg.sim, list(cfg.boundary_conditions), list(cfg.forces), classes
        )
        from motionphysics.scene.prepare import object_overlap

        error = object_overlap(
            _np(sim_scene.particles), _np(sim_scene.object_id), float(sim_scene.dx), names
        )
        if error is not None:
            raise UserInputError(error)
        counts = np.bincount(_np(sim_scene.object_id).astype(np.int64), minlength=len(ocfgs))
        observer.message(
            "info",
            f"scene: {len(ocfgs)} objects, {sim_scene.splats.num} splats, "
            + ", ".join(f"{n} {int(c)} particles" for n, c in zip(names, counts, strict=True)),
        )
        if on_scene is not None:
            on_scene(sim_scene)

    one = [object_config(cfg, o) for o in ocfgs]
    need = [estimate and not material_complete(c) for c in one]
    ref_np = None
    with stage("reference render"):
        cfg, cam_note = resolve_camera(cfg, sim_scene)
        camera = camera_from_config(cfg.camera, sim_scene.source_to_world)
        background = tuple(float(v) for v in cfg.camera.background)
        ground = ground_splats(cfg, sim_scene)
        if reference_image or any(need):
            ref_np = _render_reference(sim_scene, camera, background, ground)
        if on_camera is not None:
            on_camera(cfg, cam_note, ref_np)

    ests: list[dict[str, Any] | None] = [None] * len(ocfgs)
    if any(need):
        with stage("estimate material"):
            asked = [n for n, want in zip(names, need, strict=True) if want]
            got = dict(
                zip(
                    asked,
                    estimate_objects(cfg.prompt, asked, ref_np, init_backend, announce),
                    strict=True,
                )
            )
            ests = [got.get(n) for n in names]
            observer.message(
                "info",
                f"estimate ({init_backend}): "
                + ", ".join(f"{n}: {e['class']}" for n, e in got.items()),
            )
    with stage("resolve material"):
        materials, provs = [], []
        for name, ocfg1, est in zip(names, one, ests, strict=True):
            try:
                res = resolve_material(ocfg1, est, None)
            except UserInputError as err:
                raise UserInputError(f"objects[{name}].{err}") from None
            materials.append(res["material"])
            provs.append(_provenance(est, res))
        per, resolution = resolve_scene_simulation(cfg, sim_scene, materials, names)
        objects = tuple(
            ObjectPart(
                name=name,
                material=mat,
                resolution=r,
                provenance=prov,
                initial_velocity=tuple(
                    float(v)
                    for v in (
                        o.initial_velocity
                        if o.initial_velocity is not None
                        else cfg.sim.initial_velocity
                    )
                ),
                count=int(c),
            )
            for name, mat, r, prov, o, c in zip(
                names, materials, per, provs, ocfgs, counts, strict=True
            )
        )
        backends = sorted({p["backend"] for p in provs})
        provenance = {
            "backend": backends[0] if len(backends) == 1 else ",".join(backends),
            "params_file": None,
            "objects": {name: prov for name, prov in zip(names, provs, strict=True)},
        }
        # run.yaml records each object's simulated material (re-running reproduces it)
        cfg = cfg.model_copy(
            update={
                "objects": [
                    o.model_copy(
                        update={"material": _material_block(mat, f"objects[{o.name}].material")}
                    )
                    for o, mat in zip(cfg.objects, materials, strict=True)
                ]
            }
        )
    material = SceneMaterial(objects, _np(sim_scene.object_id).astype(np.int64))
    return Assembly(
        cfg=cfg,
        device=device,
        needs_grad=needs_grad,
        sim_scene=sim_scene,
        camera=camera,
        camera_note=cam_note,
        background=background,
        ground=ground,
        material=material,
        provenance=provenance,
        resolution=resolution,
        observer=observer,
        reference_image=ref_np,
        objects=objects,
        scene_notes=_scene_notes(ground_note, sim_scene, observer, capture),
    )


class ObjectsSimulator:
    """The differentiable simulator of a scene of several objects: one parameter vector
    per object.

    ``simulate(per_object_sim, initial_velocity, frames, grad_mode, window)`` takes one
    ``{name: 0-dim tensor}`` of simulation values per object (in object order) and
    spreads them over that object's particles (:func:`sim.per_object`), so gradients
    reach each object's own values; ``initial_velocity``: [3], [P, 3] or None (each
    object's own). Returns ``(xs [S,P,3], Fs [S,P,3,3])`` torch float32.
    """

    def __init__(self, assembly: Assembly, num_frames: int):
        self.assembly = assembly
        self.simulation = assembly.simulation
        self.num_particles = int(self.simulation.model.particle_count)
        self.num_frames = int(num_frames)
        self.object_id = _np(assembly.sim_scene.object_id).astype(np.int64)
        self.changes: list[tuple[int, int]] = []
        """(old, new) substep counts, in order, each time the count was re-resolved."""

    @property
    def substeps(self) -> int:
        return int(self.simulation.substeps)

    def _retime(self, per_object_sim) -> None:
        """Under ``substeps: auto``: the count for the current values (the stiffest
        object's CFL limit, :func:`resolve_substeps` as the forward commands resolve
        it); the rollout is rebuilt when it changes (as :class:`BridgeSimulator`)."""
        cfg = self.assembly.cfg
        if cfg.sim.substeps != "auto":
            return
        import torch

        floats = [
            {k: float(torch.as_tensor(v).detach().double()) for k, v in d.items()}
            for d in per_object_sim
        ]
        values = _per_particle_union(floats, self.object_id)
        ids = self.assembly.material.class_ids
        n = resolve_substeps(cfg, ids, values, float(self.simulation.model.dx))
        old = int(self.simulation.substeps)
        if n != old:
            self.simulation.substeps = n
            self.simulation._rollout = None
            self.changes.append((old, n))
            self.assembly.observer.message(
                "info",
                f"substeps re-resolved for the current parameters: {old} -> {n} per frame "
                "(sim.substeps: auto, CFL limit)",
            )

    def simulate(self, per_object_sim, initial_velocity, frames, grad_mode="full", window=8):
        import torch

        from motionphysics.sim.bridge import simulate
        from motionphysics.sim.model import PARAM_NAMES

        if len(per_object_sim) != len(self.assembly.objects):
            raise ValueError(
                f"{len(per_object_sim)} parameter sets for {len(self.assembly.objects)} objects"
            )
        self._retime(per_object_sim)
        params = {
            k: v
            for k, v in _per_particle_union(list(per_object_sim), self.object_id).items()
            if k in PARAM_NAMES
        }
        if initial_velocity is None:
            initial_velocity = torch.as_tensor(self.assembly.initial_velocity)
        return simulate(
            self.simulation,
            params,
            frames=frames,
            initial_velocity=initial_velocity,
            grad_mode=grad_mode,
            window=window,
        )
