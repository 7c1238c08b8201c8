"""Typed run configuration: YAML in, validated, frozen; unknown keys are errors.

The key names are a contract (README, "Config reference"): scripts and people rely on
them. Keys may be added, never renamed. Coordinates are in the world frame (after the
scene transform), z up, SI units.

``load_config(path)`` is the one entry point from files; every validation problem
becomes a :class:`~motionphysics.errors.UserInputError` whose single line names the
file, the field path and what was expected.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from motionphysics.classes import MATERIAL_CLASSES  # noqa: F401 - re-exported
from motionphysics.errors import UserInputError

Vec3 = tuple[float, float, float]
Box = tuple[Vec3, Vec3]

MaterialClassName = Literal[
    "elastic", "plasticine", "metal", "foam", "sand", "newtonian", "non_newtonian"
]


class _Strict(BaseModel):
    # NaN / Inf are never meaningful in a run config (``.nan`` in YAML is a slip).
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Region(_Strict):
    """A part of space in the world frame (after the scene transform): the selectors
    forces use, ``{box: [[x0, y0, z0], [x1, y1, z1]]}`` or ``{sphere: [[x, y, z], r]}``."""

    box: Box | None = None
    """Axis-aligned box [m], low corner then high corner."""
    sphere: tuple[Vec3, float] | None = None
    """``[[cx, cy, cz], radius]`` [m]."""

    @model_validator(mode="after")
    def _one_shape(self):
        if (self.box is None) == (self.sphere is None):
            raise ValueError("a region needs exactly one of 'box' or 'sphere'")
        if self.box is not None and not all(a < b for a, b in zip(*self.box, strict=True)):
            raise ValueError("box: [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max")
        if self.sphere is not None and not self.sphere[1] > 0:
            raise ValueError("sphere: [[x, y, z], r] with a radius r > 0")
        return self


UpAxis = Literal["z", "y", "x", "-z", "-y", "-x"]


class SceneConfig(_Strict):
    source: str = "builtin:sphere"
    """``builtin:NAME``, an INRIA 3DGS ``.ply``, or a mesh (.obj .stl .off .glb, mesh .ply)."""
    scale: float = Field(1.0, gt=0)
    """Uniform scale applied first [-]."""
    rotate: list[tuple[Literal["x", "y", "z"], float]] = []
    """Rotations ``[[axis, degrees], ...]`` applied in order after scaling."""
    translate: Vec3 = (0.0, 0.0, 0.0)
    """Translation [m] applied last."""
    opacity_threshold: float = Field(0.02, ge=0, lt=1)
    """Splats with opacity below this are dropped before simulation."""
    crop: tuple[float, float, float, float, float, float] | None = None
    """World-frame box ``[xmin, xmax, ymin, ymax, zmin, zmax]`` [m]: the splats outside it
    are discarded (neither simulated nor drawn; see ``region`` to keep them)."""
    up: UpAxis | Vec3 = "z"
    """The capture's vertical axis in its own coordinates: ``z`` (the world's), ``y``
    (Brush and many nerfstudio exports), ``x``, a negated axis (``-y``: COLMAP's y points
    down), or a vector ``[ux, uy, uz]`` (a capture whose floor is tilted). Applied first,
    as the shortest rotation taking it to +z; then ``scale``, ``rotate``, ``translate``."""
    region: Region | None = None
    """Simulate only the splats inside this region (world frame, after the transform):
    ``{box: [[x0, y0, z0], [x1, y1, z1]]}`` or ``{sphere: [[x, y, z], r]}``. The other
    splats (above ``opacity_threshold`` or not) stay where they are, are drawn in every
    frame and exported, and hold the simulated ones up (``static_collider``). Unlike
    ``crop``, which discards the splats outside it."""
    static_collider: Literal["frictional", "sticky", "slip", "off"] = "frictional"
    """With ``region``: how the static splats near the simulated region act on it: a
    fixed collider (a level set of the cells they occupy, at a quarter of the grid
    spacing) with Coulomb friction ``static_friction``, sticky (v = 0), slip, or ``off``
    (drawn only); see docs/capture.md."""
    static_friction: float = Field(0.3, ge=0)
    """Coulomb coefficient of the ``frictional`` static collider."""
    fill: bool = True
    """Fill the interior of closed objects with invisible particles (PhysGaussian)."""
    max_particles: int = Field(20000, gt=0)
    """Cap on simulated particles (visible + interior)."""
    max_anisotropy: float = Field(4.0, ge=1.0)
    """Cap on the ratio of largest to smallest splat scale (anisotropy regularisation)."""
    shade: bool = True
    """Bake a default-light shading into the colours of a mesh that has no colours or
    texture (scene.mesh); false: flat mid grey."""
    split: Literal["label", "components"] | None = None
    """Split one 3DGS scene into objects: by the per-splat integer property
    ``split_property`` of the .ply (``label``) or by connected components of the splat
    centres (``components``, largest first); each part becomes an object (see
    ``objects:``), named by ``split_names`` or ``part<id>``."""
    split_property: str = "label"
    """The per-splat .ply property ``split: label`` reads."""
    split_names: list[str] | None = None
    """Names of the parts in order (labels ascending, components by size)."""
    part: int | None = None
    """With ``split`` inside an ``objects:`` entry: which part this object is (the label
    value, or the component's rank by size, 0 = largest)."""

    @field_validator("crop")
    @classmethod
    def _crop_ordered(cls, c):
        if c is not None and not (c[0] < c[1] and c[2] < c[3] and c[4] < c[5]):
            raise ValueError("[xmin, xmax, ymin, ymax, zmin, zmax] with min < max")
        return c

    @field_validator("up")
    @classmethod
    def _up_nonzero(cls, u):
        if not isinstance(u, str) and not sum(a * a for a in u) > 0:
            raise ValueError("a non-zero vector [ux, uy, uz], or one of z, y, x, -z, -y, -x")
        return u

    @model_validator(mode="after")
    def _static_keys_need_region(self):
        # (run.yaml writes every key: only values other than the defaults need a region)
        given = [
            k
            for k in ("static_collider", "static_friction")
            if getattr(self, k) != type(self).model_fields[k].default
        ]
        if given and self.region is None:
            raise ValueError(
                f"{sorted(given)[0]}: only with scene.region (the splats outside it are "
                "the static scene)"
            )
        return self


class MaterialConfig(_Strict):
    """Given fields override the estimate from the prompt."""

    class_: MaterialClassName | None = Field(None, alias="class")
    """Material class (null: estimated from the prompt)."""
    density: float | None = Field(None, gt=0)
    """Density [kg/m^3]."""
    E: float | None = None
    """Young's modulus [Pa]."""
    nu: float | None = None
    """Poisson's ratio [-]."""
    tau_Y: float | None = None
    """Yield stress [Pa]."""
    eta: float | None = None
    """Plastic viscosity [-] (foam, non-Newtonian)."""
    theta_fric: float | None = None
    """Friction angle [degrees] (sand)."""
    mu: float | None = None
    """Viscosity [Pa s] (fluids)."""
    kappa: float | None = None
    """Bulk modulus [Pa] (fluids)."""
    n: float | None = None
    """Herschel-Bulkley power-law index [-] (non-Newtonian; 1 = Bingham)."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False
    )

    @field_validator("density", "E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n")
    @classmethod
    def _physical(cls, v, info):
        # Physically impossible values (a negative modulus, nu > 0.5) are mistakes; the
        # handbook ranges are not laws and are checked (with a warning) when resolving.
        if v is None:
            return v
        from motionphysics.materials.catalog import physical_problem

        problem = physical_problem(info.field_name, v)
        if problem is not None:
            raise ValueError(f"{problem} (physically impossible)")
        return v

    @model_validator(mode="after")
    def _params_of_the_class(self):
        # A parameter the given class does not have is a mistake (it would be ignored).
        if self.class_ is None:
            return self
        from motionphysics.materials.catalog import MATERIALS

        names = MATERIALS[self.class_].names
        extra = [k for k in self.overrides() if k != "density" and k not in names]
        if extra:
            raise ValueError(
                f"parameter(s) {', '.join(extra)} do not belong to class {self.class_} "
                f"(expected {', '.join(names)})"
            )
        return self

    def overrides(self) -> dict[str, float]:
        """The physical parameters given in the config (class excluded)."""
        out = {}
        for name in ("density", "E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n"):
            value = getattr(self, name)
            if value is not None:
                out[name] = float(value)
        return out


class InitConfig(_Strict):
    """How the material is estimated from the prompt."""

    ranges: Literal["extended", "paper"] = "extended"
    """Range table the estimates are clamped into: ``extended`` (gels to oozing fluids, see
    ``materials.catalog``) or ``paper`` (the paper's table exactly, for its ablation)."""


class SimConfig(_Strict):
    domain: Box | None = None
    """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` [m]; null: fitted around the scene."""
    grid: int = Field(64, ge=8, le=512)
    """Cells along the longest side of the domain (of a fitted domain: before the cells a
    liquid, paste or sand gets to spread into at the same cell size)."""
    frames: int = Field(48, ge=1)
    """Output frames (frame 0 is the initial state)."""
    frame_dt: float = Field(0.04, gt=0)
    """Time between output frames [s] (the video plays at 1 / frame_dt frames per second)."""
    substeps: int | Literal["auto"] = "auto"
    """Substeps per frame, or ``auto`` (the default: the CFL count of the simulated
    values, which are the physical ones wherever the difference could be seen, within
    ``max_substeps``)."""
    max_substeps: int = Field(2048, ge=1)
    """Budget of ``substeps: auto`` [substeps per frame]: the most it may spend so that
    stiffness and viscosity are simulated as asked; where the budget forces a visible
    change the run says so in one line, with the consequence."""
    gravity: Vec3 = (0.0, 0.0, -9.8)
    """Gravity [m/s^2]; the world is z-up."""
    initial_velocity: Vec3 = (0.0, 0.0, 0.0)
    """Initial velocity of all particles [m/s]."""

    @field_validator("substeps")
    @classmethod
    def _positive_substeps(cls, v):
        if isinstance(v, int) and v < 1:
            raise ValueError("an integer >= 1 or 'auto'")
        return v

    @field_validator("domain")
    @classmethod
    def _domain_ordered(cls, d):
        if d is not None and not all(a < b for a, b in zip(d[0], d[1], strict=True)):
            raise ValueError("[[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max")
        return d


class TimeWindow(_Strict):
    start: float = 0.0
    """Start time [s] (or substep index when ``unit: substeps``)."""
    end: float = 1.0e9
    """End time [s] (or substep index when ``unit: substeps``)."""
    unit: Literal["seconds", "substeps"] = "seconds"
    """What ``start`` and ``end`` count: seconds of simulated time or substeps."""


class _BCBase(TimeWindow):
    pass


class ClampGrid(_BCBase):
    """Grid nodes inside a box get an imposed velocity (e.g. a held end)."""

    type: Literal["clamp_grid"]
    box: Box
    """Region [m] whose grid nodes are clamped."""
    velocity: Vec3 = (0.0, 0.0, 0.0)
    """Velocity imposed on those nodes [m/s]."""
    axis: tuple[bool, bool, bool] = (True, True, True)
    """Which velocity components are clamped."""


class BoundingBox(_BCBase):
    """Walls on the faces of the simulation domain, with friction or a thicker layer
    (without one the faces are slip walls all the same)."""

    type: Literal["bounding_box"]
    friction: float = Field(0.0, ge=0)
    """Coulomb friction on the domain walls (0: slip)."""
    padding: int = Field(3, ge=2)
    """Thickness of the wall layer in cells."""


class SurfaceCollider(_BCBase):
    """An infinite plane (the ground, a wall, a table) or a cutting plane."""

    type: Literal["surface_collider"]
    point: Vec3 = (0.0, 0.0, 0.0)
    """A point on the plane [m]."""
    normal: Vec3 = (0.0, 0.0, 1.0)
    """Plane normal, pointing into the free side."""
    mode: Literal["sticky", "slip", "frictional", "cut"] = "frictional"
    """``sticky`` (grid velocity set to zero at the plane), ``slip`` (the velocity into the
    plane removed), ``frictional`` (slip with Coulomb friction), ``cut`` (material in the
    region removed, its velocity damped)."""
    friction: float | None = Field(None, ge=0)
    """Coulomb friction coefficient of the frictional mode (absent: 0.3); must be 0 or
    absent with sticky (null in a resolved config means absent)."""
    box: Box | None = None
    """For ``cut``: the region whose material is removed and whose grid velocity is damped
    (without a box: the half-space behind the plane)."""
    damping: float = Field(1.0, ge=0, le=1)
    """For ``cut``: fraction of velocity removed per substep inside the region."""


BoundaryCondition = Annotated[
    ClampGrid | BoundingBox | SurfaceCollider, Field(discriminator="type")
]


class _ForceBase(TimeWindow):
    box: Box | None = None
    """Particles selected by an axis-aligned box [m] (or give ``sphere``; neither: all)."""
    sphere: tuple[Vec3, float] | None = None
    """Particles selected by ``[[cx, cy, cz], radius]`` [m]."""

    @model_validator(mode="after")
    def _at_most_one_region(self):
        if self.box is not None and self.sphere is not None:
            raise ValueError("give 'box' or 'sphere', not both")
        return self


class AddConstantForce(_ForceBase):
    """A constant acceleration on the selected particles during the window."""

    type: Literal["add_constant_force"]
    force: Vec3
    """Body force per unit mass [m/s^2] (an acceleration) on the selected particles."""


class AddImpulse(_ForceBase):
    """A sudden velocity change of the selected particles (a push, a hit)."""

    type: Literal["add_impulse"]
    force: Vec3
    """Velocity change [m/s] of the selected particles (an impulse per unit mass), delivered
    within the substep holding ``start``, or evenly over ``[start, end)`` when ``end`` is
    given."""
    end: float | None = None
    """End time [s] (or substep index) of the window the impulse is spread over; absent or
    null: the whole impulse is delivered within the substep holding ``start``."""


class ForceParticlesTranslation(_ForceBase):
    """The selected particles move with an imposed velocity during the window."""

    type: Literal["force_particles_translation"]
    velocity: Vec3
    """Velocity [m/s] imposed on the selected particles during the window."""
    axis: tuple[bool, bool, bool] = (True, True, True)
    """Which velocity components are imposed."""


class ForceParticlesRotation(_ForceBase):
    """The selected particles rotate about an axis during the window."""

    type: Literal["force_particles_rotation"]
    center: Vec3
    """Point on the rotation axis [m]."""
    axis_direction: Vec3 = (0.0, 0.0, 1.0)
    """Rotation axis direction."""
    angular_velocity: float
    """Angular velocity [rad/s] imposed on the selected particles during the window."""


class ReleaseParticles(_ForceBase):
    """The selected particles are held, then released layer by layer."""

    type: Literal["release_particles"]
    layers: int = Field(1, ge=1)
    """Selected particles are frozen (held in place, v = 0) from t = 0 and released in this
    many equal-width layers: layer l (0 = highest) at ``start + (l + 1) (end - start) / layers``."""
    release_axis: Literal["x", "y", "z"] = "z"
    """Axis the layers are stacked along; the layer with the largest coordinate goes first."""
    end: float | None = None
    """Time [s] (or substep index) the last layer is released (required; null: missing)."""


Force = Annotated[
    AddConstantForce
    | AddImpulse
    | ForceParticlesTranslation
    | ForceParticlesRotation
    | ReleaseParticles,
    Field(discriminator="type"),
]


class CameraConfig(_Strict):
    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True
    )

    azimuth: float = 30.0
    """Azimuth [degrees], counter-clockwise from +x about the up axis."""
    elevation: float = 20.0
    """Elevation [degrees] above the horizontal plane."""
    radius: float = Field(2.5, gt=0)
    """Distance from look_at [m]. With neither ``radius`` nor ``look_at`` given (and no
    ``cameras_json``) the camera frames the object and the ground below it automatically
    and ``run.yaml`` records the radius it chose."""
    look_at: Vec3 = (0.0, 0.0, 0.3)
    """Point the camera looks at [m] (see ``radius``: left out, it is chosen by the framing)."""
    fov: float = Field(45.0, gt=1, lt=179)
    """Vertical field of view [degrees]."""
    width: int = Field(256, ge=8, le=4096)
    """Image width [px]."""
    height: int = Field(256, ge=8, le=4096)
    """Image height [px]."""
    background: Vec3 = (1.0, 1.0, 1.0)
    """RGB in [0, 1]."""
    cameras_json: str | None = None
    """Optional INRIA cameras.json; with it, ``camera_index`` picks the view (the older
    spelling of ``from``; give one of them)."""
    from_: str | None = Field(None, alias="from")
    """A capture's cameras: an INRIA ``cameras.json`` or a nerfstudio ``transforms.json``
    (told apart by their content); ``camera_index`` picks the view. The cameras are in
    the capture's frame and follow the scene transform (``up``, ``scale``, ``rotate``,
    ``translate``) into the world; the image is resized to ``width`` x ``height``."""
    camera_index: int = Field(0, ge=0)
    """Which camera of ``from`` / ``cameras_json`` is used."""

    @model_validator(mode="after")
    def _one_camera_file(self):
        if self.from_ is not None and self.cameras_json is not None:
            raise ValueError("from: give from or cameras_json, not both")
        return self

    @property
    def camera_file(self) -> str | None:
        """``from`` or ``cameras_json`` (the capture's camera file), or None."""
        return self.from_ or self.cameras_json

    show_ground: bool = True
    """Draw the ground (the highest upward-facing surface collider) as a grey checker floor
    in the video and the reference image; render only, never simulated."""


DEFAULT_LOSS = "lmd"
"""The refinement's loss when the config names none (the paper's learnable motion
distillation; registered by the priors package)."""


class LossSpec(BaseModel):
    """One entry of ``optimize.losses``: ``{type: NAME, weight: W, ...options}``.

    ``type`` names a loss of the ``LOSSES`` registry; the other keys are that loss's
    own options, validated by its ``Options`` model (``LOSSES.options``). Names and
    options are checked against the registries by
    :func:`motionphysics.runconfig.check_plugins` (this module imports no plug-in
    package: the registries' packages depend on it).
    """

    model_config = ConfigDict(extra="allow", frozen=True)
    type: str
    """A registered loss name (``motionphysics.losses.LOSSES``)."""
    weight: float = Field(1.0, ge=0)
    """Factor of this loss in the weighted sum."""

    def options(self) -> dict[str, Any]:
        """The loss's own options (every key but ``type`` and ``weight``)."""
        return dict(self.model_extra or {})


class OptimizeConfig(_Strict):
    prior: str = "none"
    """``none`` (no refinement) or a video prior of the ``PRIORS`` registry."""
    prior_path: str | None = None
    """Model directory of the prior (``save_pretrained`` layout); None: the prior's default."""
    loss: str | None = None
    """Short form of ``losses: [{type: NAME}]``: a loss of the ``LOSSES`` registry
    (null: ``lmd``, learnable motion distillation, checked when used)."""
    losses: list[LossSpec] | None = None
    """Weighted losses, ``[{type: NAME, weight: W, ...options}]``; wins over ``loss``."""
    guidance: float | None = Field(None, ge=0)
    """Classifier-free guidance scale for every prior loss that has a ``guidance`` option
    and does not set its own (``--guidance W``); None: each loss's own default (lmd /
    sds 100 as in the paper, flow / video 6 for the sampled reference)."""
    iterations: int = Field(40, ge=0)
    """Optimisation iterations (0: none)."""
    boost: int = Field(8, ge=1)
    """Frame boosting: number M of interleaved subsequences. With a video prior it is
    capped so that each subsequence has at least min(the prior's frames, 16) frames
    (the run's params.json records the M used)."""
    grad_mode: Literal["full", "window", "last_substep"] = "full"
    """Gradients through every substep (``full``, checkpointed), the last ``window``
    substeps before each supervised frame, or only the last substep."""
    window: int = Field(8, ge=1)
    """Substeps before each supervised frame that gradients flow through (grad_mode: window)."""
    seed: int = 0
    """Seed of the optimisation's random draws (diffusion steps, noise, subsequences)."""
    lr: float = Field(0.05, gt=0)
    """Adam learning rate on the unconstrained vector theta."""
    lr_per_param: dict[str, float] = {}
    """Per-parameter learning rates, by parameter name."""
    warmup: int = Field(2, ge=0)
    """Warm-up iterations of the cosine schedule."""
    params: list[str] | dict[str, list[str]] | None = None
    """Parameters to optimise (default: all of the class's parameters, density excluded).
    Several objects (``objects:``): a list applies to every object; a mapping by object
    name (``{duck: [E], block: [E, nu]}``) gives each object its own list, and an object
    it leaves out keeps its material as given."""
    tolerance: float = Field(1e-4, ge=0)
    """Stop early when the relative change of theta stays below this for 3 iterations."""
    per_particle: list[str] = []
    """Parameters optimised as per-particle fields instead of scene-wide values."""
    initial_velocity: bool = False
    """Also optimise ``sim.initial_velocity`` (its rate: ``lr_per_param.initial_velocity``)."""
    ssim_weight: float = Field(0.2, ge=0, le=1)
    """video_match: weight w of ``(1 - SSIM)`` in ``(1 - w) L1 + w (1 - SSIM)``."""
    trajectory_metric: Literal["l2", "chamfer"] = "l2"
    """trajectory_match: ``l2`` (corresponding particles) or ``chamfer`` (point sets)."""
    global_search: bool = True
    """``fit``: a forward-only global stage before the gradient stage (a log-grid scan
    of the optimised parameter, or a Latin hypercube over theta for several); the
    gradient stage starts from its best candidate. ``fit --no-global`` turns it off."""
    global_points: int = Field(9, ge=2)
    """Global stage: candidates of the coarse scan (per optimised parameter for a
    Latin hypercube), spread evenly over the handbook range in theta."""
    global_refine: int = Field(4, ge=0)
    """Global stage: extra candidates between the best coarse candidate's neighbours."""
    global_patience: int = Field(3, ge=0)
    """Global stage, one parameter: stop the ascending scan after this many consecutive
    candidates each scoring worse than 10x the best so far (the stiff end of a range
    costs the most substeps under ``auto`` and is rarely close); 0: scan every point."""
    global_frames: int | None = Field(None, ge=2)
    """Global stage: frames simulated per candidate (a short horizon is cheaper);
    None: all of ``sim.frames``."""
    curriculum: float = Field(0.25, ge=0, le=1)
    """Gradient stage: fraction of the iterations over which the supervised horizon
    grows from the first quarter of the frames to all of them (early frames first,
    for oscillating motion whose error is not convex in stiffness); 0: all frames
    from the start."""

    @model_validator(mode="before")
    @classmethod
    def _one_loss_form(cls, data: Any) -> Any:
        # ``loss`` mirrors the first entry of ``losses`` (so run.yaml, which holds both,
        # reads back); a ``loss`` that says something else is a contradiction.
        if not isinstance(data, dict) or data.get("losses") is None:
            return data
        losses = data["losses"]
        if not isinstance(losses, list) or not losses:
            raise ValueError("optimize.losses: expected a list of {type: NAME, weight: W} entries")
        first = losses[0].get("type") if isinstance(losses[0], dict) else None
        if "loss" in data and first is not None and data["loss"] != first:
            raise ValueError(
                f"optimize.loss ({data['loss']!r}) and optimize.losses (first {first!r}) "
                "disagree; give one of them"
            )
        return {**data, "loss": first} if first is not None else data

    def loss_specs(self) -> list[LossSpec]:
        """The configured losses: ``losses``, or ``[{type: loss}]`` (the short form)."""
        if self.losses is not None:
            return list(self.losses)
        return [LossSpec(type=self.loss or DEFAULT_LOSS)]


MAX_OBJECTS = 8
"""Most objects one scene may hold (the simulator keeps one grid velocity field each)."""


class ObjectConfig(SceneConfig):
    """One object of a scene of several (``objects:``): its own scene keys, material and
    initial velocity. ``max_particles`` is this object's share of the particles."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z][A-Za-z0-9 _-]*$")
    """What the object is called; the init backends look for it in the prompt."""
    material: MaterialConfig = MaterialConfig()
    """Given fields override the estimate for this object."""
    initial_velocity: Vec3 | None = None
    """Initial velocity of this object's particles [m/s] (absent: ``sim.initial_velocity``)."""
    prompt: str | None = Field(None, min_length=1)
    """This object's phrase for a prior that observes each object (``--prior motion``):
    what its motion should look like ("the jelly cube wobbles"). Absent: the clause of
    the run's ``prompt`` that names the object (:func:`motionphysics.optimize.objects.object_prompt`)."""


def _check_objects_optimize(opt: OptimizeConfig, objects, several: bool) -> None:
    """The ``optimize`` keys that depend on how many objects there are."""
    if isinstance(opt.params, dict):
        if not several:
            raise ValueError(
                "optimize.params: a mapping by object name needs objects: (or scene.split); "
                "give a list of parameter names"
            )
        if not opt.params:
            raise ValueError("optimize.params: empty mapping; name at least one object")
        if objects is not None:
            names = [o.name for o in objects]
            unknown = [k for k in opt.params if k not in names]
            if unknown:
                raise ValueError(
                    f"optimize.params: {', '.join(unknown)} not an object of this scene; "
                    f"expected names among {', '.join(names)}"
                )
    if several and opt.per_particle:
        raise ValueError(
            "optimize.per_particle: per-particle fields are for one object; with several "
            "objects each object's parameters are optimised as one value each"
        )
    if several and opt.initial_velocity:
        raise ValueError(
            "optimize.initial_velocity: with several objects each keeps its own initial "
            "velocity (objects[i].initial_velocity); it is not optimised"
        )


class RunConfig(_Strict):
    scene: SceneConfig = SceneConfig()
    prompt: str = "An elastic ball hits the ground and bounces back."
    """Text prompt: the material is estimated from it, a prior is guided by it."""
    material: MaterialConfig = MaterialConfig()
    init: InitConfig = InitConfig()
    """Material estimation: ``ranges`` (``extended`` or ``paper``)."""
    sim: SimConfig = SimConfig()
    boundary_conditions: list[BoundaryCondition] | None = None
    """Grid conditions and colliders. Left out (null): a frictional floor at z = 0 (under
    the scene's lowest point when the scene reaches below z = 0; when the scene would stand
    on it and the prompt asks for a fall or a bounce that nothing in the config starts,
    one object height under it, or less so that it lands within the first 40 % of the
    clip, so it falls), said in the summary and written to
    ``run.yaml``; ``[]``: free space (no ground). The faces of the simulation domain are
    walls either way."""
    forces: list[Force] = []
    camera: CameraConfig = CameraConfig()
    optimize: OptimizeConfig = OptimizeConfig()
    device: Literal["cpu", "cuda"] = "cpu"
    """Where to simulate and render."""
    export_ply: bool = False
    """Write INRIA-format splats per frame to ``splats/``."""
    versions: dict[str, str] = {}
    """Informational: package versions that wrote this config (run.yaml); ignored on input."""
    objects: list[ObjectConfig] | None = None
    """Several objects, each with its own scene keys, ``material:`` and ``initial_velocity``
    (null: the one object of ``scene:`` + ``material:``). With ``objects:`` the ``scene:``
    and ``material:`` blocks must be left out."""

    @model_validator(mode="after")
    def _objects_or_scene(self):
        several = self.objects is not None or self.scene.split is not None
        _check_objects_optimize(self.optimize, self.objects, several)
        if self.objects is None:
            if self.scene.part is not None:
                raise ValueError("scene.part: only inside an objects: entry (with split)")
            return self
        if not self.objects:
            raise ValueError("objects: expected a list of at least one {name, source, ...} entry")
        if len(self.objects) > MAX_OBJECTS:
            raise ValueError(f"objects: at most {MAX_OBJECTS} objects, got {len(self.objects)}")
        for i, o in enumerate(self.objects):
            if (o.split is None) != (o.part is None):
                raise ValueError(
                    f"objects[{i}]: split and part go together (which part of the split scene)"
                )
            if o.split_names is not None:
                raise ValueError(f"objects[{i}].split_names: name the object with name:")
        names = [o.name for o in self.objects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"objects: names must differ, {', '.join(dup)} given twice")
        # run.yaml holds the default blocks; anything else beside ``objects:`` is ambiguous
        if self.scene != SceneConfig() or self.material != MaterialConfig():
            raise ValueError(
                "objects: give each object's scene keys and material inside its entry, not "
                "in scene: / material: beside objects:"
            )
        return self

    def object_configs(self) -> list[ObjectConfig]:
        """The objects of the scene: ``objects:``, or the one of ``scene:`` + ``material:``."""
        if self.objects is not None:
            return list(self.objects)
        return [
            ObjectConfig(
                name="object", material=self.material, **self.scene.model_dump(by_alias=True)
            )
        ]


# --- error messages ---------------------------------------------------------------------
# Every validation problem becomes ONE line: ``FILE: field.path: got VALUE; expected WHAT``
# (unknown keys: ``FILE: field.path: unknown key; did you mean `frames`?``). The field path
# is walked through the models so union/discriminator tags pydantic adds to ``loc`` (``int``,
# ``literal['auto']``, ``surface_collider``) never appear as if they were keys.

_MISSING = object()


def _unwrap(tp: Any) -> Any:
    """Strip ``Annotated`` and ``| None`` from an annotation."""
    import typing

    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _members(tp: Any) -> list[Any]:
    import types
    import typing

    tp = _unwrap(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return [_unwrap(a) for a in typing.get_args(tp) if a is not type(None)]
    return [tp]


def _model_of(tp: Any, tag: Any = None) -> type[BaseModel] | None:
    """The pydantic model an annotation holds (the union member with ``type == tag``)."""
    models = [m for m in _members(tp) if isinstance(m, type) and issubclass(m, BaseModel)]
    if tag is not None:
        for m in models:
            f = m.model_fields.get("type")
            if f is not None and tag in getattr(f.annotation, "__args__", ()):
                return m
    return models[0] if len(models) == 1 else None


def _field(model: type[BaseModel], key: str):
    for name, f in model.model_fields.items():
        if key in (name, f.alias):
            return f
    return None


def _keys(model: type[BaseModel]) -> list[str]:
    return [f.alias or name for name, f in model.model_fields.items()]


def _walk(loc: tuple[Any, ...]) -> tuple[str, type[BaseModel] | None, Any]:
    """(user path, model holding the last key, annotation of the last key) of a ``loc``."""
    import typing

    parts: list[str] = []
    tp: Any = RunConfig
    parent: type[BaseModel] | None = None
    for item in loc:
        model = _model_of(tp)
        if isinstance(item, int):
            parts.append(f"[{item}]")
            inner = [a for m in _members(tp) for a in typing.get_args(m)]
            tp = inner[0] if len(inner) == 1 or (inner and inner[-1] is not Ellipsis) else Any
            if inner and len(inner) > 1 and inner[-1] is not Ellipsis and item < len(inner):
                tp = inner[item]
            continue
        if model is None:
            # Inside a union of models: a discriminator tag selects the member.
            tagged = _model_of(tp, tag=item)
            if tagged is not None and _field(tagged, str(item)) is None:
                tp = tagged
                continue
            model = tagged
        if model is not None and _field(model, str(item)) is not None:
            parts.append(("." if parts else "") + _key(item))
            parent = model
            tp = _field(model, str(item)).annotation
            continue
        if model is not None and isinstance(tp, type) and issubclass(tp, BaseModel):
            # An unknown key of a model (extra_forbidden).
            parts.append(("." if parts else "") + _key(item))
            parent = model
            tp = Any
            continue
        # A union member tag (``int``, ``literal['auto']``, ``tuple[...]``) or a dict key.
        if typing.get_origin(_unwrap(tp)) is dict or (
            model is None
            and not any(ch in str(item) for ch in "[]")
            and str(item) not in ("int", "float", "str", "bool", "none", "list", "tuple")
        ):
            parts.append(("." if parts else "") + _key(item))
            tp = Any
    return "".join(parts) or "(top level)", parent, tp


def _key(item: Any) -> str:
    """A key as it can be shown on one line (control characters and blanks escaped, at most
    :data:`KEY_SHOWN` characters: an error line stays one short line whatever the key)."""
    text = str(item)
    shown = text if text.isprintable() and text.strip() == text and text else repr(text)
    return shown if len(shown) <= KEY_SHOWN else shown[: KEY_SHOWN - 3] + "..."


KEY_SHOWN = 20
"""Characters of a key shown in an error line."""


def _show(value: Any) -> str:
    text = repr(value) if not isinstance(value, str) else repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 60 else text[:57] + "..."


def _expected(e: dict[str, Any]) -> str:
    t = e.get("type", "")
    ctx = e.get("ctx") or {}
    if t == "literal_error":
        choices = str(ctx.get("expected", "?"))
        return (
            choices
            if "," not in choices and " or " not in choices
            else "one of " + choices.replace(" or ", ", ")
        )
    if t in ("int_parsing", "int_type", "int_from_float"):
        return "an integer"
    if t in ("float_parsing", "float_type"):
        return "a number"
    if t in ("bool_parsing", "bool_type"):
        return "true or false"
    if t in ("string_type",):
        return "a text string"
    if t in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<"}.get(t, "<=")
        bound = next(iter(ctx.values()), "?")
        return f"a number {op} {bound}"
    if t in ("finite_number",):
        return "a finite number"
    if t in ("model_type", "model_attributes_type", "dict_type"):
        return "a mapping of keys (key: value)"
    if t in ("list_type", "tuple_type", "iterable_type"):
        return "a list"
    if t in ("too_short", "too_long"):
        return f"{ctx.get('min_length', ctx.get('max_length', '?'))} items"
    if t == "union_tag_invalid":
        return f"type: one of {ctx.get('expected_tags', '?')}".replace(" or ", ", ")
    if t == "union_tag_not_found":
        return f"a {ctx.get('discriminator', 'type')} key naming the kind of entry"
    msg = str(e.get("msg", "a valid value"))
    return msg.removeprefix("Value error, ").removeprefix("Assertion failed, ")


def _closest(word: str, choices: list[str]) -> str | None:
    import difflib

    hit = difflib.get_close_matches(word, choices, n=1, cutoff=0.6)
    if not hit:  # case / separator slips: "Frames", "frame-dt"
        norm = {c.lower().replace("-", "_"): c for c in choices}
        hit = (
            [norm[word.lower().replace("-", "_")]] if word.lower().replace("-", "_") in norm else []
        )
    return hit[0] if hit else None


def format_validation_error(err: ValidationError, origin: str) -> str:
    """One line for a pydantic error: file, field path, the value given, what was expected.

    Errors of one field (the members of a union such as ``int | 'auto'``, the missing
    items of a short tuple) are merged; when several fields are wrong the first is
    named and the count of the others is appended.
    """
    groups: dict[str, list[dict[str, Any]]] = {}
    meta: dict[str, tuple[type[BaseModel] | None, Any]] = {}
    for e in err.errors():
        loc = tuple(e.get("loc", ()))
        # Items missing from a short tuple/list: report the list itself.
        if e.get("type") == "missing" and loc and isinstance(loc[-1], int):
            loc = loc[:-1]
            e = {**e, "type": "too_short", "ctx": {"min_length": _tuple_len(loc)}}
        path, parent, tp = _walk(loc)
        groups.setdefault(path, []).append(e)
        meta.setdefault(path, (parent, tp))
    path, errs = next(iter(groups.items()))
    parent, _ = meta[path]
    e = errs[0]
    t = e.get("type")
    more = len(groups) - 1
    tail = f" (and {more} more problem{'s' if more > 1 else ''})" if more else ""
    if t == "extra_forbidden":
        raw = tuple(errs[0].get("loc", ()))[-1:] or ("",)
        key = _key(raw[0])
        hint = ""
        if parent is not None:
            near = _closest(key, _keys(parent))
            hint = (
                f"; did you mean `{near}`?"
                if near
                else f"; expected one of {', '.join(_keys(parent))}"
            )
        return f"{origin}: {path}: unknown key `{key}`{hint}{tail}"
    if t == "missing":
        return f"{origin}: {path}: missing (required){tail}"
    value = e.get("input", _MISSING)
    expected = " or ".join(dict.fromkeys(_expected(x) for x in errs))
    if t == "literal_error" and isinstance(value, str):
        choices = re.findall(r"'([^']*)'", str((e.get("ctx") or {}).get("expected", "")))
        near = _closest(value, choices)
        if near:
            expected += f" (did you mean `{near}`?)"
    if t == "union_tag_invalid":
        value = (e.get("ctx") or {}).get("tag", value)
        path = f"{path}.type"
    if t in ("value_error", "assertion_error") and isinstance(value, dict):
        return f"{origin}: {path}: {expected}{tail}"
    shown = "nothing" if value is _MISSING else _show(value)
    return f"{origin}: {path}: got {shown}; expected {expected}{tail}"


def _tuple_len(loc: tuple[Any, ...]) -> int | str:
    import typing

    _, _, tp = _walk(loc)
    for m in _members(tp):
        args = typing.get_args(m)
        if typing.get_origin(m) is tuple and args and args[-1] is not Ellipsis:
            return len(args)
    return "?"


def config_from_dict(data: dict[str, Any], origin: str = "<config>") -> RunConfig:
    """Validate a mapping into a :class:`RunConfig`; errors name ``origin`` and the field."""
    if not isinstance(data, dict):
        raise UserInputError(f"{origin}: expected a YAML mapping at the top level")
    try:
        return RunConfig.model_validate(data)
    except ValidationError as err:
        raise UserInputError(format_validation_error(err, origin)) from None


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a YAML run config."""
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path}: config file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise UserInputError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    return config_from_dict(data, str(path))


def config_to_dict(cfg: RunConfig) -> dict[str, Any]:
    """The fully resolved config as plain data (what ``run.yaml`` holds)."""
    return cfg.model_dump(mode="json", by_alias=True)


def dump_config(cfg: RunConfig) -> str:
    """YAML text of the fully resolved config; ``load_config`` reads it back equal."""
    return yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
