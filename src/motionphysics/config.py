"""Typed run configuration: YAML in, validated, frozen; unknown keys are errors.

The key names are a contract (DESIGN.md, "Run config"): scripts and people rely on
them. Keys may be added, never renamed. Coordinates are in the world frame (after the
scene transform), z up, SI units.

``load_config(path)`` is the one entry point from files; every validation problem
becomes a :class:`~motionphysics.errors.UserInputError` whose single line names the
file, the field path and what was expected.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from motionphysics.errors import UserInputError

Vec3 = tuple[float, float, float]
Box = tuple[Vec3, Vec3]

MATERIAL_CLASSES = (
    "elastic",
    "plasticine",
    "metal",
    "foam",
    "sand",
    "newtonian",
    "non_newtonian",
)
MaterialClassName = Literal[
    "elastic", "plasticine", "metal", "foam", "sand", "newtonian", "non_newtonian"
]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


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
    """World-frame box ``[xmin, xmax, ymin, ymax, zmin, zmax]`` [m] kept for simulation."""
    fill: bool = True
    """Fill the interior of closed objects with invisible particles (PhysGaussian)."""
    max_particles: int = Field(20000, gt=0)
    """Cap on simulated particles (visible + interior)."""
    max_anisotropy: float = Field(4.0, ge=1.0)
    """Cap on the ratio of largest to smallest splat scale (anisotropy regularisation)."""

    @model_validator(mode="after")
    def _crop_ordered(self):
        if self.crop is not None:
            c = self.crop
            if not (c[0] < c[1] and c[2] < c[3] and c[4] < c[5]):
                raise ValueError("crop must be [xmin, xmax, ymin, ymax, zmin, zmax] with min < max")
        return self


class MaterialConfig(_Strict):
    """Given fields override the estimate from the prompt."""

    class_: MaterialClassName | None = Field(None, alias="class")
    density: float | None = Field(None, gt=0)
    """kg/m^3."""
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

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    def overrides(self) -> dict[str, float]:
        """The physical parameters given in the config (class excluded)."""
        out = {}
        for name in ("density", "E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n"):
            value = getattr(self, name)
            if value is not None:
                out[name] = float(value)
        return out


class SimConfig(_Strict):
    domain: Box | None = None
    """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` [m]; null: fitted around the scene."""
    grid: int = Field(64, ge=8, le=512)
    """Cells along the longest side of the domain."""
    frames: int = Field(48, ge=1)
    """Output frames (frame 0 is the initial state)."""
    frame_dt: float = Field(0.04, gt=0)
    """Seconds between output frames."""
    substeps: int | Literal["auto"] = 64
    """Substeps per frame, or ``auto`` (from the CFL condition of the stiffest material)."""
    gravity: Vec3 = (0.0, 0.0, -9.8)
    """Gravity [m/s^2]; the world is z-up."""
    initial_velocity: Vec3 = (0.0, 0.0, 0.0)
    """Initial velocity of all particles [m/s]."""

    @field_validator("substeps")
    @classmethod
    def _positive_substeps(cls, v):
        if isinstance(v, int) and v < 1:
            raise ValueError("substeps must be >= 1 or 'auto'")
        return v

    @model_validator(mode="after")
    def _domain_ordered(self):
        if self.domain is not None:
            lo, hi = self.domain
            if not all(a < b for a, b in zip(lo, hi, strict=True)):
                raise ValueError(
                    "domain must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max"
                )
        return self


class TimeWindow(_Strict):
    start: float = 0.0
    """Start time [s] (or substep index when ``unit: substeps``)."""
    end: float = 1.0e9
    """End time [s] (or substep index when ``unit: substeps``)."""
    unit: Literal["seconds", "substeps"] = "seconds"


class _BCBase(TimeWindow):
    pass


class ClampGrid(_BCBase):
    type: Literal["clamp_grid"]
    box: Box
    """Region [m] whose grid nodes are clamped."""
    velocity: Vec3 = (0.0, 0.0, 0.0)
    """Velocity imposed on those nodes [m/s]."""
    axis: tuple[bool, bool, bool] = (True, True, True)
    """Which velocity components are clamped."""


class BoundingBox(_BCBase):
    type: Literal["bounding_box"]
    friction: float = Field(0.0, ge=0)
    """Coulomb friction on the domain walls (0: slip)."""
    padding: int = Field(3, ge=2)
    """Thickness of the wall layer in cells."""


class SurfaceCollider(_BCBase):
    type: Literal["surface_collider"]
    point: Vec3 = (0.0, 0.0, 0.0)
    """A point on the plane [m]."""
    normal: Vec3 = (0.0, 0.0, 1.0)
    """Plane normal, pointing into the free side."""
    mode: Literal["sticky", "slip", "frictional", "cut"] = "frictional"
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


class Region(_Strict):
    box: Box | None = None
    """Axis-aligned box [m]."""
    sphere: tuple[Vec3, float] | None = None
    """``[[cx, cy, cz], radius]`` [m]."""

    @model_validator(mode="after")
    def _one_shape(self):
        if (self.box is None) == (self.sphere is None):
            raise ValueError("a region needs exactly one of 'box' or 'sphere'")
        return self


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
    type: Literal["add_constant_force"]
    force: Vec3
    """Body force per unit mass [m/s^2] (an acceleration) on the selected particles."""


class AddImpulse(_ForceBase):
    type: Literal["add_impulse"]
    force: Vec3
    """Velocity change [m/s] of the selected particles (an impulse per unit mass), delivered
    within the substep holding ``start``, or evenly over ``[start, end)`` when ``end`` is
    given."""


class ForceParticlesTranslation(_ForceBase):
    type: Literal["force_particles_translation"]
    velocity: Vec3
    """Velocity [m/s] imposed on the selected particles during the window."""
    axis: tuple[bool, bool, bool] = (True, True, True)


class ForceParticlesRotation(_ForceBase):
    type: Literal["force_particles_rotation"]
    center: Vec3
    """Point on the rotation axis [m]."""
    axis_direction: Vec3 = (0.0, 0.0, 1.0)
    """Rotation axis direction."""
    angular_velocity: float
    """Angular velocity [rad/s] imposed on the selected particles during the window."""


class ReleaseParticles(_ForceBase):
    type: Literal["release_particles"]
    layers: int = Field(1, ge=1)
    """Selected particles are frozen (held in place, v = 0) from t = 0 and released in this
    many equal-width layers: layer l (0 = highest) at ``start + (l + 1) (end - start) / layers``."""
    release_axis: Literal["x", "y", "z"] = "z"
    """Axis the layers are stacked along; the layer with the largest coordinate goes first."""


Force = Annotated[
    AddConstantForce
    | AddImpulse
    | ForceParticlesTranslation
    | ForceParticlesRotation
    | ReleaseParticles,
    Field(discriminator="type"),
]


class CameraConfig(_Strict):
    azimuth: float = 30.0
    """Degrees, counter-clockwise from +x about the up axis."""
    elevation: float = 20.0
    """Degrees above the horizontal plane."""
    radius: float = Field(2.5, gt=0)
    """Distance from look_at [m]."""
    look_at: Vec3 = (0.0, 0.0, 0.3)
    fov: float = Field(45.0, gt=1, lt=179)
    """Vertical field of view [degrees]."""
    width: int = Field(256, ge=8, le=4096)
    height: int = Field(256, ge=8, le=4096)
    background: Vec3 = (1.0, 1.0, 1.0)
    """RGB in [0, 1]."""
    cameras_json: str | None = None
    """Optional INRIA cameras.json; with it, ``camera_index`` picks the view."""
    camera_index: int = 0
    show_ground: bool = True
    """Draw the ground (the highest upward-facing surface collider) as a grey checker floor
    in the video and the reference image; render only, never simulated."""


class OptimizeConfig(_Strict):
    prior: Literal["none", "tiny", "cogvideox", "modelscope"] = "none"
    loss: Literal["lmd", "sds", "flow", "video_match", "trajectory_match"] = "lmd"
    iterations: int = Field(40, ge=0)
    boost: int = Field(8, ge=1)
    """Frame boosting: number M of interleaved subsequences."""
    grad_mode: Literal["full", "window", "last_substep"] = "full"
    window: int = Field(8, ge=1)
    """Substeps before each supervised frame that gradients flow through (grad_mode: window)."""
    seed: int = 0
    lr: float = Field(0.05, gt=0)
    """Adam learning rate on the unconstrained vector theta."""
    lr_per_param: dict[str, float] = {}
    """Per-parameter learning rates, by parameter name."""
    warmup: int = Field(2, ge=0)
    """Warm-up iterations of the cosine schedule."""
    params: list[str] | None = None
    """Parameters to optimise (default: all of the class's parameters, density excluded)."""
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


class RunConfig(_Strict):
    scene: SceneConfig = SceneConfig()
    prompt: str = "An elastic ball hits the ground and bounces back."
    material: MaterialConfig = MaterialConfig()
    sim: SimConfig = SimConfig()
    boundary_conditions: list[BoundaryCondition] = []
    forces: list[Force] = []
    camera: CameraConfig = CameraConfig()
    optimize: OptimizeConfig = OptimizeConfig()
    device: Literal["cpu", "cuda"] = "cpu"
    export_ply: bool = False
    """Write INRIA-format splats per frame to ``splats/``."""
    versions: dict[str, str] = {}
    """Informational: package versions that wrote this config (run.yaml); ignored on input."""


def _format_loc(loc: tuple[Any, ...]) -> str:
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f"[{item}]")
        else:
            # Discriminated-union tags appear as a path element; they are not user keys.
            if (
                item
                in {
                    "clamp_grid",
                    "bounding_box",
                    "surface_collider",
                    "add_constant_force",
                    "add_impulse",
                    "force_particles_translation",
                    "force_particles_rotation",
                    "release_particles",
                }
                and parts
            ):
                continue
            parts.append(("." if parts else "") + str(item))
    return "".join(parts) or "(top level)"


def _first_error(err: ValidationError) -> str:
    e = err.errors()[0]
    loc = _format_loc(tuple(e.get("loc", ())))
    msg = e.get("msg", "invalid value")
    if e.get("type") == "extra_forbidden":
        msg = "unknown key (check the spelling against DESIGN.md's run config)"
    return f"{loc}: {msg}"


def config_from_dict(data: dict[str, Any], origin: str = "<config>") -> RunConfig:
    """Validate a mapping into a :class:`RunConfig`; errors name ``origin`` and the field."""
    if not isinstance(data, dict):
        raise UserInputError(f"{origin}: expected a YAML mapping at the top level")
    try:
        return RunConfig.model_validate(data)
    except ValidationError as err:
        raise UserInputError(f"{origin}: {_first_error(err)}") from None


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
