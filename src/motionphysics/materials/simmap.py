"""The one map between physical material values (SI) and simulation values.

The explicit MLS-MPM solver is stable only while the fastest elastic wave crosses
less than a fraction of a cell per substep (``c <= c_max = cfl * dx / dt``,
``cfl = 0.4``) and the explicit viscous diffusion stays below its limit
(``mu <= 0.5 * density * dx^2 / (6 dt)``); see CONTRACTS.md. Steel (E = 2e11 Pa,
c ~ 5 km/s) cannot be integrated at the resolutions and time steps of a run of a
few minutes, so this module compresses stiffness, and *only* this module: callers
report both values, nothing else scales parameters.

Rules, per parameter (``lo``/``hi`` = the class's handbook range from
:mod:`~motionphysics.materials.catalog`; all maps are strictly monotone,
continuous, invertible, and identity wherever the value can be seen in this scene and
the time-step budget allows it):

``nu``  (solids) identity below 0.45; ``[0.45, 0.5]`` is mapped linearly onto
        ``[0.45, 0.49]`` so nearly incompressible solids (rubber, nu = 0.5) keep a
        finite P-wave modulus: ``(1-nu)/((1+nu)(1-2nu))`` is 17 at 0.49, infinite
        at 0.5.
``E``   (elastic, plasticine, metal, foam) simulated **as given** up to a knee, compressed
        above it: ``log E`` affine from ``[log knee, log hi_eff]`` onto
        ``[log knee, log top]``. ``cap = density c_max^2 / M(nu_sim)`` is the stiffest
        value the time step allows (``c_max`` from the budget: ``sim.max_substeps`` under
        ``substeps: auto``, the fixed count otherwise); ``E_vis``
        (:func:`visible_stiffness`) the stiffness above which every strain a viewer could
        see in this scene stays below ``visible_strain`` (0.5 % of the object's size);
        ``knee = min(E_vis, cap / 1.25)``, ``top = min(cap, 2 knee)``,
        ``hi_eff = max(class high, 4 top)``. So a stiffness that shows is simulated as
        asked whenever the budget allows it, one that cannot be seen is compressed to
        just above ``E_vis`` (order kept: steel stays stiffer than rubber; cost that of
        ``E_vis``), and where the budget forces a visible change the plan says so in one
        line with the consequence (:func:`visible_changes`).

What can be seen (per object, from the prepared scene and the config: ``SimContext``'s
``speed_met``, ``thickness``, ``length``, ``gravity``, ``frame_dt``, ``duration``):

* sag under its own weight and bending of its slender part:
  ``rho g L / E max(1, 2 (L / t)^2)`` (a round cantilever of length ``L``, thickness
  ``t`` sags ``2 rho g L^4 / (E t^2)``);
* the squash of an impact at the largest speed it meets ``v`` (drop onto the support
  below it, initial, imposed and impulse velocities, rotations, other objects):
  ``v / c`` with ``c = sqrt(E / rho)``, counted by the share of a frame the contact
  (``2 L / c``) lasts: a squash over in a millisecond is not in a 25 fps video;
* vibrations: an elastic wave crossing the object in less than a quarter of a frame is
  not resolved (floor ``E_vis >= rho (4 L / frame_dt)^2``);
* viscous flow (:func:`visible_viscosity`): ``rho L (g T + v) / mu`` of its size over
  the run ``T``.

``tau_Y`` (plasticine, metal, foam) follows the compressed ``E`` by one of two rules.
        Both cannot hold at once once ``E`` is compressed: ``rho c v / tau_Y`` and
        ``tau_Y / E`` fix ``c`` when ``rho`` and ``v`` are physical.

        ``strain``: scaled by ``E_sim / E``, the yield strain ``tau_Y / E`` is kept,
        so what bends permanently in reality bends in the simulation at the same
        strain. Under an impact the elastic strain is ``v / c``; with ``c``
        compressed to ``c_max`` it grows by ``c / c_max``, so the ratio of impact
        stress to yield stress grows by ``c / c_sim``.

        ``impact``: scaled by ``c_sim / c`` (P-wave speeds), the ratio of elastic
        impact stress ``rho c v`` to yield stress is kept for every impact speed
        ``v`` (:func:`impact_to_yield`): what dents in reality dents, what rebounds
        rebounds. The yield strain grows by ``c / c_sim`` instead.

        ``auto`` (``SimContext.yield_rule``'s default) picks per class: **metal**
        keeps the impact ratio, **plasticine and foam** keep the yield strain. Why:
        a metal's yield strain (~1e-3) is invisible, what a viewer sees of metal is
        that it keeps its shape when dropped or knocked (steel from a 0.75 m table:
        impact/yield 0.70 in reality, 72 in the simulation at grid 64, dt =
        frame_dt/512 under ``strain``: it would dent like clay), and metal is the
        class whose stiffness is compressed by orders of magnitude (c ~ 5 km/s vs
        c_max ~ 10-100 m/s). Plasticine and foam yield at visible strains (4e-3 to
        1: squashed clay, crushed foam), so the yield strain (how far they squash
        before staying squashed) is what a viewer sees, and their stiffness is
        compressed far less (at dt = frame_dt/512 about 1-20x, so the impact ratio
        drifts by at most ~4x: foam dropped 0.75 m stays below yield, 0.2-0.5 vs 0.1;
        clay dents either way, 36 vs 34). The price for metal: its simulated yield
        strain is ``c / c_sim`` times the real one (steel 0.13 at grid 64), so
        bending a rod permanently takes a larger push than in reality.
        Each rule is a positive factor of ``E``, ``E_sim`` and ``nu`` only, so
        ``tau_Y`` maps linearly (monotone, invertible, differentiable).
``kappa`` (fluids) replaced by the weakly compressible value of SPH/MPM fluid
        solvers: ``kappa_sim = kappa * s`` (order and the hi/lo ratio kept), ``s``
        chosen so the sound speed ``sqrt(kappa_sim / density)`` at ``kappa = lo``
        is ``10 v`` (``v``: the largest speed met, at least ``sqrt(2 g L)``) (density fluctuations ~ Ma^2 <= 1 %), capped so
        the speed at ``kappa = hi`` is at most ``c_max`` (with ``g = 0``: at ``c_max``).
``mu``  (fluids, dynamic viscosity) the stiffness rule with ``mu_vis``
        (:func:`visible_viscosity`) and the explicit viscosity limit
        ``0.5 * density * dx^2 / (6 dt)`` as the cap: a viscosity that shows is
        simulated as asked within the budget (honey included), one too large to show
        over the run is compressed just above ``mu_vis``.
``eta``, ``theta_fric`` (degrees), ``n`` and ``density`` pass through.
``tau_Y`` (non-Newtonian) is not compressed (it sets a mound height ``tau_Y/(rho g)``
        against gravity, which is not compressed either) but converted: the
        catalogue's value is the rheometer's SHEAR yield stress (toothpaste ~200 Pa,
        ketchup ~20 Pa), while the solver's ``tau_Y`` is the UNIAXIAL von Mises
        yield stress (``sim.constitutive.herschel_bulkley``: shear yield =
        ``tau_Y / sqrt(3)``), so ``tau_Y_sim = sqrt(3) tau_Y``. Passed through
        unchanged, a paste yielded at 58 % of its stress and a 10 cm toothpaste blob
        slumped like dry sand (final height 0.23 vs sand 0.26; with the factor 0.35).

Non-Newtonian (Herschel-Bulkley) simulation keys follow the constitutive model's
arguments (``sim.constitutive.herschel_bulkley``), not the catalogue's names:
``eta`` (sim) = ``2^((n+1)/2) K`` where the consistency ``K`` [Pa s^n] is the
catalogue's ``mu`` (a viscosity, paper table 1e-3..1e3 Pa s) mapped with the viscosity
rule above; the factor turns the solver's strain-space flow rule into the rheological
``tau = tau_y + K gamma_dot^n`` in simple shear (:func:`nn_consistency_factor`);
``mu`` (sim) = the elastic shear modulus [Pa] of the unyielded paste =
``eta * NN_SHEAR_FRACTION * kappa_sim``: the paper's unitless "plastic viscosity"
``eta`` in [0.1, 1] is read as the stiffness of the unyielded state relative to
the stable maximum (the only reading in which a unitless factor is meaningful;
decided by the lead, see CONTRACTS.md). ``kappa_sim`` for this class is reduced by
``1 + 4/3 NN_SHEAR_FRACTION`` so the P-wave speed ``sqrt((kappa + 4/3 mu)/rho)``
stays within ``c_max``.

Sand's Drucker-Prager return map needs an elastic predictor that the catalogue
does not parameterise: the map adds derived ``E`` and ``nu = 0.3`` for sand with
the P-wave speed ``min(c_max, 10 sqrt(2 g L))`` (a stiff, stable skeleton).

Every function works on python floats and on torch tensors (scalars or
per-particle ``[P]``), differentiably; ``SimContext`` fields are python floats.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from motionphysics.materials.catalog import MATERIALS, MaterialParams, normalise_class

__all__ = [
    "nn_consistency_factor",
    "SimContext",
    "physical_to_sim",
    "sim_to_physical",
    "p_wave_speed",
    "p_wave_modulus_factor",
    "impact_to_yield",
    "yield_rule_for",
    "YIELD_RULES",
    "NU_SIM_MAX",
    "NN_YIELD_FACTOR",
    "SAND_NU",
    "ClassViolation",
    "class_violations",
    "substeps_keeping_class",
    "plan_substeps",
    "SubstepPlan",
    "MAX_AUTO_SUBSTEPS",
    "SIM_QUANTITIES",
    "sim_quantities",
    "mapped_substitutions",
]

NU_KNEE = 0.45
"""Poisson's ratios up to this pass through unchanged."""
NU_SIM_MAX = 0.49
"""Simulation Poisson's ratio of a physical 0.5 (incompressible)."""
NU_PHYS_MAX = 0.5
ORDER_RATIO = 2.0
"""Stiffness (and viscosity) that cannot be seen is compressed into ``[knee, 2 knee]``
above the visible threshold: the order of materials survives (steel stays stiffer than
rubber), the cost stays that of the visible threshold."""
BUDGET_RATIO = 1.25
"""Where the budget binds (the visible threshold is above what it allows), values up to
``cap / 1.25`` are simulated as asked and stiffer ones compressed into the last 25 %."""
MACH_FACTOR = 10.0
"""Fluid sound speed at kappa = lo, in units of the flow speed sqrt(2 g L)."""
MU_KNEE_FACTOR = 10.0
"""Viscosities below (viscosity limit / this) pass through unchanged."""
SAND_NU = 0.3
"""Poisson's ratio of sand's derived elastic predictor."""
NN_YIELD_FACTOR = math.sqrt(3.0)
"""Non-Newtonian: solver (uniaxial von Mises) yield stress over the catalogue's shear yield stress."""
NN_SHEAR_FRACTION = 0.375
"""Non-Newtonian: shear modulus of the unyielded paste at eta = 1, as a fraction of kappa_sim."""


def nn_consistency_factor(n):
    """Solver ``eta`` over the rheological consistency ``K`` of a Herschel-Bulkley paste.

    ``sim.constitutive.herschel_bulkley`` writes its flow rule in deviatoric strain space;
    in steady simple shear it reads ``tau = tau_Y/sqrt(3) + eta 2^(-(n+1)/2) gamma_dot^n``
    (its docstring), so the catalogue's ``mu`` (= K, as a rheometer measures it) enters
    the solver as ``eta = K 2^((n+1)/2)`` (2 K for Bingham, n = 1). Float or tensor ``n``.
    """
    return 2.0 ** ((n + 1.0) / 2.0)


YIELD_RULES = ("auto", "strain", "impact")
"""Values of ``SimContext.yield_rule``."""
AUTO_YIELD_RULE = {"metal": "impact", "plasticine": "strain", "foam": "strain"}
"""The rule ``yield_rule='auto'`` applies per class (module docstring: why)."""

_SOLIDS = ("elastic", "plasticine", "metal", "foam")
_YIELD_SCALED = ("plasticine", "metal", "foam")


@dataclass(frozen=True)
class SimContext:
    """What the map needs to know about the simulation it feeds.

    Built by the sim helper and the pipeline; with ``substeps: auto`` the pipeline
    maps with ``dt = frame_dt / 512`` (CONTRACTS.md).
    """

    dx: float
    """Grid spacing [m]."""
    dt: float
    """Substep [s]."""
    density: float
    """Mass density of the material being mapped [kg/m^3] (sets the wave-speed caps)."""
    length: float
    """Characteristic size of the simulated object [m] (longest side of its bounding box)."""
    gravity: float = 9.8
    """Magnitude of gravity [m/s^2] (sets the flow speed sqrt(2 g L) and own-weight stress)."""
    cfl: float = 0.4
    """Fraction of a cell the fastest wave may cross per substep."""
    yield_rule: Literal["auto", "strain", "impact"] = "auto"
    """How ``tau_Y`` of plasticine, metal and foam follows a compressed ``E``:
    ``strain`` keeps the yield strain ``tau_Y / E``; ``impact`` keeps the ratio of
    elastic impact stress ``rho c v`` to yield stress (``tau_Y`` scaled by
    ``c_sim / c``), so a dropped metal object rebounds instead of denting when the
    time step forces a large stiffness compression; ``auto`` (default): ``impact``
    for metal, ``strain`` for plasticine and foam (module docstring)."""

    speed_met: float | None = None
    """Largest speed [m/s] the object meets in this scene (a drop under gravity, initial,
    imposed and impulse velocities, the rim speed of imposed rotations, closing speeds of
    several objects); None: the fall over its own size, ``sqrt(2 g L)``."""
    thickness: float | None = None
    """Thickness [m] of the object's most slender part (bending sag grows with
    ``(L / thickness)^2``); None: a compact object (``length``)."""
    frame_dt: float = 0.04
    """Seconds between output frames (what a viewer can resolve)."""
    duration: float | None = None
    """Simulated time of the run [s] (how long a slow flow has to show); None: 2 s."""
    visible_strain: float = 0.005
    """Strain a viewer can see (0.5 % of the object's size: about one pixel of a
    200-pixel object); below it a change of stiffness or viscosity is invisible."""

    def __post_init__(self):
        for name in ("dx", "dt", "density", "length", "frame_dt"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"SimContext.{name} must be a positive finite number, got {v!r}")
        if self.yield_rule not in YIELD_RULES:
            raise ValueError(
                f"SimContext.yield_rule must be one of {', '.join(YIELD_RULES)}, "
                f"got {self.yield_rule!r}"
            )
        if not (self.gravity >= 0 and math.isfinite(self.gravity)):
            raise ValueError(f"SimContext.gravity must be >= 0, got {self.gravity!r}")

    @property
    def c_max(self) -> float:
        """Largest stable P-wave speed [m/s]: ``cfl * dx / dt``."""
        return self.cfl * self.dx / self.dt

    @property
    def mu_max(self) -> float:
        """Explicit viscosity limit [Pa s]: ``0.5 * density * dx^2 / (6 dt)``."""
        return 0.5 * self.density * self.dx**2 / (6.0 * self.dt)

    @property
    def flow_speed(self) -> float:
        """Characteristic flow / impact speed [m/s]: ``sqrt(2 g L)`` (free fall over L)."""
        return math.sqrt(2.0 * self.gravity * self.length)

    @property
    def speed(self) -> float:
        """Largest speed [m/s] the object meets: ``speed_met``, at least ``flow_speed``."""
        return max(self.flow_speed, self.speed_met or 0.0)

    @property
    def thickness_or_length(self) -> float:
        return self.thickness if self.thickness else self.length

    @property
    def run_time(self) -> float:
        """Simulated time [s] (``duration``, or 2 s when unknown)."""
        return self.duration if self.duration else 2.0


# --- float / tensor neutral helpers -------------------------------------------------


def _is_tensor(x: Any) -> bool:
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def _like(x: Any, ref: Any):
    import torch

    return torch.as_tensor(x, dtype=ref.dtype, device=ref.device)


def _log(x):
    if _is_tensor(x):
        import torch

        return torch.log(x)
    return math.log(x)


def _exp(x):
    if _is_tensor(x):
        import torch

        return torch.exp(x)
    return math.exp(x)


def _minimum(a, b):
    if _is_tensor(a) or _is_tensor(b):
        import torch

        ref = a if _is_tensor(a) else b
        return torch.minimum(_like(a, ref), _like(b, ref))
    return min(a, b)


def _maximum(a, b):
    if _is_tensor(a) or _is_tensor(b):
        import torch

        ref = a if _is_tensor(a) else b
        return torch.maximum(_like(a, ref), _like(b, ref))
    return max(a, b)


def _where(cond, a, b):
    if _is_tensor(cond) or _is_tensor(a) or _is_tensor(b):
        import torch

        ref = next(x for x in (a, b, cond) if _is_tensor(x) and x.is_floating_point())
        return torch.where(
            _like(cond, ref).bool() if not _is_tensor(cond) else cond, _like(a, ref), _like(b, ref)
        )
    return a if cond else b


# --- the per-parameter maps ----------------------------------------------------------


def _nu_to_sim(nu):
    compressed = NU_KNEE + (nu - NU_KNEE) * ((NU_SIM_MAX - NU_KNEE) / (NU_PHYS_MAX - NU_KNEE))
    return _where(nu <= NU_KNEE, nu, compressed)


def _nu_from_sim(nu_sim):
    expanded = NU_KNEE + (nu_sim - NU_KNEE) * ((NU_PHYS_MAX - NU_KNEE) / (NU_SIM_MAX - NU_KNEE))
    return _where(nu_sim <= NU_KNEE, nu_sim, expanded)


def p_wave_modulus_factor(nu):
    """``M(nu) = (1-nu) / ((1+nu)(1-2nu))``: P-wave modulus ``lambda + 2 mu = E M(nu)``."""
    return (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))


def visible_stiffness(ctx: SimContext) -> float:
    """``E_vis`` [Pa]: the stiffness above which every strain a viewer could see in this
    scene stays below ``ctx.visible_strain`` (module docstring, "What can be seen").

    The largest of: own weight and bending under gravity
    (``rho g L / eps * max(1, 2 (L / t)^2)``: a round cantilever of length ``L`` and
    thickness ``t`` sags ``2 rho g L^4 / (E t^2)``), the impact strain ``v / c_bar`` at
    the largest speed the object meets, counted in proportion to how long the contact
    lasts against a frame (:func:`visible_strains`), and the floor
    ``rho (4 L / frame_dt)^2`` (an elastic wave crossing the object in a quarter of a
    frame: vibrations faster than that are not resolved by the video).
    """
    eps = ctx.visible_strain
    rho, L = ctx.density, ctx.length
    t = min(ctx.thickness_or_length, L)
    weight = rho * ctx.gravity * L / eps * max(1.0, 2.0 * (L / t) ** 2)
    # impact: the bar wave speed c at which the impact strain (visible_strains) is eps
    v_eps = ctx.speed / eps
    c_impact = min(v_eps, math.sqrt(v_eps * 2.0 * L / ctx.frame_dt))
    floor = 4.0 * L / ctx.frame_dt
    return max(weight, rho * c_impact**2, rho * floor**2)


def _E_bounds(cls: str, nu_sim, ctx: SimContext):
    """(knee, top, hi_eff) of the stiffness map: identity up to ``knee``, then ``log E``
    affine from ``[log knee, log hi_eff]`` onto ``[log knee, log top]``.

    ``cap = density c_max^2 / M(nu_sim)`` is the stiffest value the time step allows
    (the budget); ``knee = min(E_vis, cap / BUDGET_RATIO)`` and
    ``top = min(cap, ORDER_RATIO knee)``: stiffness that cannot be seen is compressed
    to just above ``E_vis`` (order kept, cheap); where ``E_vis`` is above what the budget
    allows, the knee is the budget's and the change is visible (:func:`visible_changes`).
    ``hi_eff = max(class high, ORDER_RATIO^2 top)`` (knee, top may be tensors).
    """
    hi = MATERIALS[cls].param("E").high
    # (1 - 1e-6: the CFL count of the top value must not round up past the budget)
    cap = ctx.density * ctx.c_max**2 / p_wave_modulus_factor(nu_sim) * (1.0 - 1e-6)
    knee = _minimum(visible_stiffness(ctx), cap / BUDGET_RATIO)
    top = _minimum(cap, knee * ORDER_RATIO)
    hi_eff = _maximum(hi, top * ORDER_RATIO**2)
    return knee, top, hi_eff


def _E_to_sim(cls, E, nu_sim, ctx):
    knee, top, hi_eff = _E_bounds(cls, nu_sim, ctx)
    slope = (_log(top) - _log(knee)) / (_log(hi_eff) - _log(knee))
    E_safe = _maximum(E, knee)  # the compressed branch is only taken above the knee
    compressed = _exp(_log(knee) + (_log(E_safe) - _log(knee)) * slope)
    return _where(E <= knee, E, compressed)


def _E_from_sim(cls, E_sim, nu_sim, ctx):
    knee, top, hi_eff = _E_bounds(cls, nu_sim, ctx)
    slope = (_log(top) - _log(knee)) / (_log(hi_eff) - _log(knee))
    E_safe = _maximum(E_sim, knee)
    expanded = _exp(_log(knee) + (_log(E_safe) - _log(knee)) / slope)
    return _where(E_sim <= knee, E_sim, expanded)


def _kappa_scale(cls: str, ctx: SimContext) -> float:
    ps = MATERIALS[cls].param("kappa")
    c_lo = MACH_FACTOR * ctx.speed
    kappa_hi_sim = ctx.density * ctx.c_max**2
    if c_lo > 0:  # without gravity there is no flow-speed scale: use the stable maximum
        kappa_hi_sim = min(kappa_hi_sim, ctx.density * c_lo**2 * ps.high / ps.low)
    if cls == "non_newtonian":  # room for the shear modulus in the P-wave speed
        kappa_hi_sim /= 1.0 + 4.0 / 3.0 * NN_SHEAR_FRACTION
    return kappa_hi_sim / ps.high


def visible_viscosity(ctx: SimContext) -> float:
    """``mu_vis`` [Pa s]: the viscosity above which a body's viscous flow moves it less than
    ``visible_strain`` of its size over the run: ``rho L (g T + v) / eps`` (a blob of size
    ``L`` flows at ``rho g L^2 / mu`` under its weight for ``T`` seconds; a velocity ``v``
    imposed on it deforms it by ``rho v L / mu`` before viscosity stops it); at least
    ``rho L^2 / T`` (viscous diffusion across the object within the run)."""
    driven = ctx.density * ctx.length * (ctx.gravity * ctx.run_time + ctx.speed)
    # floor (nothing drives a flow): viscous diffusion over the object in the run time
    return max(driven / ctx.visible_strain, ctx.density * ctx.length**2 / ctx.run_time)


def _mu_bounds(cls: str, ctx: SimContext):
    """(knee, top, hi_eff) of the viscosity map (the stiffness map's rule, with the
    explicit viscosity limit ``0.5 density dx^2 / (6 dt)`` as the budget's cap)."""
    hi = MATERIALS[cls].param("mu").high
    cap = ctx.mu_max * (1.0 - 1e-6)
    knee = min(visible_viscosity(ctx), cap / BUDGET_RATIO)
    top = min(cap, knee * ORDER_RATIO)
    return knee, top, max(hi, top * ORDER_RATIO**2)


def _mu_to_sim(cls, mu, ctx):
    knee, top, hi = _mu_bounds(cls, ctx)
    slope = (math.log(top) - math.log(knee)) / (math.log(hi) - math.log(knee))
    compressed = _exp(math.log(knee) + (_log(_maximum(mu, knee)) - math.log(knee)) * slope)
    return _where(mu <= knee, mu, compressed)


def _mu_from_sim(cls, mu_sim, ctx):
    knee, top, hi = _mu_bounds(cls, ctx)
    slope = (math.log(top) - math.log(knee)) / (math.log(hi) - math.log(knee))
    expanded = _exp(math.log(knee) + (_log(_maximum(mu_sim, knee)) - math.log(knee)) / slope)
    return _where(mu_sim <= knee, mu_sim, expanded)


def yield_rule_for(cls: str, ctx: SimContext) -> str:
    """The rule (``'strain'`` or ``'impact'``) that maps ``tau_Y`` of ``cls`` under ``ctx``."""
    if ctx.yield_rule != "auto":
        return ctx.yield_rule
    return AUTO_YIELD_RULE.get(normalise_class(cls), "strain")


def _yield_factor(cls, E_sim, nu_sim, E, nu, ctx: SimContext):
    """tau_Y_sim / tau_Y: E_sim/E (yield strain kept) or c_sim/c (impact ratio kept)."""
    if yield_rule_for(cls, ctx) == "strain":
        return E_sim / E
    return ((E_sim * p_wave_modulus_factor(nu_sim)) / (E * p_wave_modulus_factor(nu))) ** 0.5


def _sand_E(ctx: SimContext) -> float:
    c = min(ctx.c_max, MACH_FACTOR * ctx.speed) if ctx.speed > 0 else ctx.c_max
    return ctx.density * c**2 / p_wave_modulus_factor(SAND_NU)


# --- public API ----------------------------------------------------------------------


def _split(params: MaterialParams | Mapping[str, Any], cls: str | None):
    if isinstance(params, MaterialParams):
        return params.cls, dict(params.values), params.density
    values = dict(params)
    given = values.pop("class", None)
    cls = cls if cls is not None else given
    if cls is None:
        raise ValueError("physical_to_sim: give a MaterialParams, a dict with 'class', or cls=")
    density = values.pop("density", None)
    return normalise_class(cls), values, density


def physical_to_sim(
    params: MaterialParams | Mapping[str, Any], ctx: SimContext, cls: str | None = None
) -> dict[str, Any]:
    """Simulation values of a material (floats or torch tensors, differentiable).

    ``params``: a :class:`MaterialParams`, or a mapping of physical values (SI,
    ``density`` optional; ``class`` optional, e.g. ``MaterialParams.to_dict()``)
    together with ``cls`` when it has no ``class``; every parameter of the class is
    needed except those with a default (``n``: left out, the simulator uses 1). Values should lie in the class's
    ranges (validate first); outside them the maps extend monotonically but the
    stability guarantee holds only inside.

    Returns a dict with the class's parameter names, ``density`` (when known; passes
    through) and, for sand, the derived ``E`` and ``nu``.
    """
    cls, values, density = _split(params, cls)
    missing = [
        ps.name for ps in MATERIALS[cls].params if ps.name not in values and ps.default is None
    ]
    if missing:
        raise ValueError(f"physical_to_sim: class {cls} needs {', '.join(missing)}")
    out: dict[str, Any] = {}
    if cls in _SOLIDS:
        nu_sim = _nu_to_sim(values["nu"])
        E_sim = _E_to_sim(cls, values["E"], nu_sim, ctx)
        out["E"] = E_sim
        out["nu"] = nu_sim
        if cls in _YIELD_SCALED:
            out["tau_Y"] = values["tau_Y"] * _yield_factor(
                cls, E_sim, nu_sim, values["E"], values["nu"], ctx
            )
        if "eta" in values:
            out["eta"] = values["eta"]
    elif cls == "sand":
        out["theta_fric"] = values["theta_fric"]
        out["E"] = _sand_E(ctx)
        out["nu"] = SAND_NU
    elif cls == "newtonian":
        out["mu"] = _mu_to_sim(cls, values["mu"], ctx)
        out["kappa"] = values["kappa"] * _kappa_scale(cls, ctx)
    else:  # non_newtonian: keys of the Herschel-Bulkley model (module docstring)
        kappa_sim = values["kappa"] * _kappa_scale(cls, ctx)
        out["kappa"] = kappa_sim
        out["eta"] = _mu_to_sim(cls, values["mu"], ctx) * nn_consistency_factor(
            values.get("n", 1.0)
        )
        out["mu"] = values["eta"] * NN_SHEAR_FRACTION * kappa_sim
        out["tau_Y"] = values["tau_Y"] * NN_YIELD_FACTOR
        if "n" in values:
            out["n"] = values["n"]
    if density is not None:
        out["density"] = density
    return out


def sim_to_physical(
    sim_values: Mapping[str, Any], ctx: SimContext, cls: str | None = None
) -> MaterialParams:
    """Inverse of :func:`physical_to_sim` (derived sand ``E``/``nu`` are dropped).

    ``cls`` may be omitted when ``sim_values`` carries a ``'class'`` key.
    """
    s = dict(sim_values)
    given = s.pop("class", None)
    if cls is None and given is None:
        raise ValueError("sim_to_physical: give cls= (or a 'class' key)")
    cls = normalise_class(cls if cls is not None else given)
    density = s.pop("density", None)
    out: dict[str, Any] = {}
    if cls in _SOLIDS:
        nu_sim = s["nu"]
        E = _E_from_sim(cls, s["E"], nu_sim, ctx)
        out["E"] = E
        out["nu"] = _nu_from_sim(nu_sim)
        if cls in _YIELD_SCALED:
            out["tau_Y"] = s["tau_Y"] / _yield_factor(cls, s["E"], nu_sim, E, out["nu"], ctx)
        if cls == "foam":
            out["eta"] = s["eta"]
    elif cls == "sand":
        out["theta_fric"] = s["theta_fric"]
    elif cls == "newtonian":
        out["mu"] = _mu_from_sim(cls, s["mu"], ctx)
        out["kappa"] = s["kappa"] / _kappa_scale(cls, ctx)
    else:
        out["mu"] = _mu_from_sim(cls, s["eta"] / nn_consistency_factor(s.get("n", 1.0)), ctx)
        out["kappa"] = s["kappa"] / _kappa_scale(cls, ctx)
        out["eta"] = s["mu"] / (NN_SHEAR_FRACTION * s["kappa"])
        out["tau_Y"] = s["tau_Y"] / NN_YIELD_FACTOR
        if "n" in s:
            out["n"] = s["n"]
    return MaterialParams(cls, density, out)


def p_wave_speed(cls: str, sim_values: Mapping[str, Any], density: Any = None):
    """Fastest elastic wave speed [m/s] of mapped values: what the CFL limit bounds.

    Solids and sand: ``sqrt(E M(nu) / density)``; Newtonian: ``sqrt(kappa / density)``;
    non-Newtonian: ``sqrt((kappa + 4/3 mu) / density)`` (sim keys).
    ``density`` defaults to ``sim_values['density']``.
    """
    cls = normalise_class(cls)
    rho = sim_values["density"] if density is None else density
    if cls == "newtonian":
        modulus = sim_values["kappa"]
    elif cls == "non_newtonian":
        modulus = sim_values["kappa"] + 4.0 / 3.0 * sim_values["mu"]
    else:
        modulus = sim_values["E"] * p_wave_modulus_factor(sim_values["nu"])
    ratio = modulus / rho
    return ratio**0.5


def impact_to_yield(sim_values: Mapping[str, Any], speed: float, density: Any = None):
    """Ratio of the elastic impact stress ``rho c v`` to the yield stress, in sim units.

    Below ~1 a solid hitting the ground at ``speed`` [m/s] rebounds elastically and
    keeps its shape; above it yields. Solids with ``tau_Y`` only.
    """
    rho = sim_values["density"] if density is None else density
    c = (sim_values["E"] * p_wave_modulus_factor(sim_values["nu"]) / rho) ** 0.5
    return rho * c * speed / sim_values["tau_Y"]


# --- the material asked for, or a clear refusal ---------------------------------------
#
# The stiffness map above keeps every run stable, but at a coarse time step it can move a
# material so far that it behaves as another class: steel at ``substeps: 5`` (E 4e11 Pa
# simulated as 1.6e4 Pa) sags flat like dough. The rule, per class, on the simulated
# values against the physical ones (``sigma_g = density * g * L``: the own-weight stress
# at the bottom of the object; ``v = sqrt(2 g L)``: the speed after falling its own size):
#
# * elastic, plasticine, foam: own-weight strain ``sigma_g / E_sim`` at most SAG_LIMIT
#   (10 %; beyond it a body visibly slumps like jelly or dough instead of keeping its
#   shape); metal: at most METAL_SAG_LIMIT (2 %: what a viewer reads as rigid).
# * plasticine, metal, foam: the yield stress must stay above the own-weight stress
#   (``sigma_g / tau_Y_sim < 1``) or the body flows under its own weight like a paste.
# * metal only: the impact-to-yield ratio at ``v`` (:func:`impact_to_yield`) must stay
#   <= 1 when it is <= 1 in reality (dropped metal rebounds; dented, it reads as clay).
# * every limit applies only where the MAP is responsible: a value a person chose soft
#   (a jelly written as E = 1e4 Pa) is simulated as written, so the simulated figure must
#   also exceed the physical one by RESPONSIBLE_FACTOR (sag) or cross 1 where the
#   physical one does not (yield, impact).
# * sand, Newtonian and non-Newtonian fluids: nothing the map compresses changes their
#   class (sand's stiffness is derived, its friction angle passes through; fluids keep
#   their yield stress and their viscosity is compressed only above the knee), so no
#   refusal; the compression is reported as ``mapped to simulation``.

SAG_LIMIT = 0.10
METAL_SAG_LIMIT = 0.02
RESPONSIBLE_FACTOR = 2.0
MAX_AUTO_SUBSTEPS = 2048
"""Default budget of ``substeps: auto`` (``sim.max_substeps``): substeps per frame."""

_LOOKS_LIKE = {
    "elastic": "slumps like jelly",
    "plasticine": "slumps like a liquid",
    "metal": "flows like dough",
    "foam": "slumps like jelly",
}


@dataclass(frozen=True)
class ClassViolation:
    """One way the simulated material leaves its class (see the rule above)."""

    rule: str
    """``sag``, ``own_weight_yield`` or ``impact``."""
    parameter: str
    physical: float
    simulated: float
    measure: float
    """The simulated figure the rule bounds (strain, stress ratio)."""
    limit: float
    text: str


def class_violations(
    params: MaterialParams, sim_values: Mapping[str, Any], ctx: SimContext
) -> list[ClassViolation]:
    """How the simulated ``sim_values`` make ``params`` behave as another class (float inputs)."""
    cls = params.cls
    if cls not in _SOLIDS:
        return []
    rho = float(params.density)
    sigma_g = rho * ctx.gravity * ctx.length
    out: list[ClassViolation] = []
    E, E_sim = float(params.values["E"]), float(sim_values["E"])
    sag_phys, sag_sim = sigma_g / E, sigma_g / E_sim
    limit = METAL_SAG_LIMIT if cls == "metal" else SAG_LIMIT
    look = _LOOKS_LIKE[cls]
    if sag_sim > limit and sag_sim > RESPONSIBLE_FACTOR * sag_phys:
        out.append(
            ClassViolation(
                "sag",
                "E",
                E,
                E_sim,
                sag_sim,
                limit,
                f"is simulated with E = {E_sim:.2g} Pa (asked {E:.2g} Pa) and "
                + (
                    f"sags {100 * sag_sim:.0f} % under its own weight ({look})"
                    if sag_sim <= 1
                    else f"its own weight strains it by more than 100 % ({look})"
                ),
            )
        )
    if cls in _YIELD_SCALED:
        tau, tau_sim = float(params.values["tau_Y"]), float(sim_values["tau_Y"])
        if sigma_g / tau_sim >= 1.0 > sigma_g / tau:
            out.append(
                ClassViolation(
                    "own_weight_yield",
                    "tau_Y",
                    tau,
                    tau_sim,
                    sigma_g / tau_sim,
                    1.0,
                    f"is simulated with tau_Y = {tau_sim:.2g} Pa (asked {tau:.2g} Pa), below "
                    f"its own-weight stress {sigma_g:.2g} Pa, so it flows under its own weight",
                )
            )
    if cls == "metal" and ctx.flow_speed > 0:
        v = ctx.flow_speed
        phys = {"E": E, "nu": float(params.values["nu"]), "tau_Y": float(params.values["tau_Y"])}
        r_phys = float(impact_to_yield(phys, v, density=rho))
        r_sim = float(impact_to_yield(sim_values, v, density=rho))
        if r_sim > 1.0 >= r_phys:
            out.append(
                ClassViolation(
                    "impact",
                    "tau_Y",
                    phys["tau_Y"],
                    float(sim_values["tau_Y"]),
                    r_sim,
                    1.0,
                    f"yields on an impact at {v:.2g} m/s (impact/yield {r_sim:.2g}, real "
                    f"{r_phys:.2g}) and dents like clay",
                )
            )
    return out


@dataclass(frozen=True)
class VisibleChange:
    """A simulated value a viewer can tell from the physical one (the budget forced it)."""

    parameter: str
    physical: float
    simulated: float
    measure: str
    """What shows the change: ``impact squash``, ``sag``, ``viscous flow``."""
    physical_strain: float
    simulated_strain: float
    text: str
    """One line: the change, its consequence in numbers, and what to do."""


_REMEDY = "use a coarser sim.grid, fewer particles or a larger sim.max_substeps"


def visible_strains(cls: str, E: float, ctx: SimContext) -> dict[str, float]:
    """Strains a viewer sees of a solid of stiffness ``E`` [Pa] in this scene:
    ``sag`` (own weight and bending, ``rho g L / E max(1, 2 (L/t)^2)``) and ``impact``
    (``v / c`` at the largest speed met, ``c = sqrt(E / rho)``, weighted by the share of
    a frame the contact lasts, ``min(1, 2 L / (c frame_dt))``: a squash over in a
    millisecond is not in the video)."""
    cls = normalise_class(cls)
    if cls not in _SOLIDS:
        return {}
    rho, L = ctx.density, ctx.length
    t = min(ctx.thickness_or_length, L)
    c = math.sqrt(E / rho)
    return {
        "sag": rho * ctx.gravity * L / E * max(1.0, 2.0 * (L / t) ** 2),
        "impact": ctx.speed / c * min(1.0, 2.0 * L / (c * ctx.frame_dt)),
    }


def visible_changes(
    params: MaterialParams, sim_values: Mapping[str, Any], ctx: SimContext
) -> list[VisibleChange]:
    """Where the simulated values look different from the physical ones in this scene.

    Solids: the stiffness is simulated softer than asked and one of its visible strains
    (:func:`visible_strains`) then exceeds both ``ctx.visible_strain`` and the physical
    strain by more than ``visible_strain``. Fluids: the viscosity is simulated below
    ``min(asked, mu_vis)`` (:func:`visible_viscosity`): the fluid flows visibly faster.
    Empty when the map changed only what cannot be seen.
    """
    cls = params.cls
    eps = ctx.visible_strain
    out: list[VisibleChange] = []
    if cls in _SOLIDS:
        E, E_sim = float(params.values["E"]), float(sim_values["E"])
        if E_sim >= E * (1 - 1e-9):
            return out
        phys, sim = visible_strains(cls, E, ctx), visible_strains(cls, E_sim, ctx)
        worst = max(sim, key=lambda k: sim[k] - phys[k])
        if sim[worst] > eps and sim[worst] - phys[worst] > eps:
            words = {"sag": "sags", "impact": "impact squash"}[worst]
            ratio = E / E_sim
            out.append(
                VisibleChange(
                    "E",
                    E,
                    E_sim,
                    worst,
                    phys[worst],
                    sim[worst],
                    f"{cls} simulated {ratio:.3g}x softer than asked (E {E:.3g} -> "
                    f"{E_sim:.3g} Pa): {words} {_pct(sim[worst])} of its size instead of "
                    f"{_pct(phys[worst])}; {_REMEDY}",
                )
            )
    elif cls in ("newtonian", "non_newtonian"):
        mu = float(params.values["mu"])
        key = "mu" if cls == "newtonian" else "eta"
        mu_sim = float(sim_values[key])
        if cls == "non_newtonian":
            mu_sim /= float(nn_consistency_factor(float(sim_values.get("n", 1.0))))
        mu_vis = visible_viscosity(ctx)
        if mu_sim < min(mu, mu_vis) * (1 - 1e-6):
            out.append(
                VisibleChange(
                    "mu",
                    mu,
                    mu_sim,
                    "viscous flow",
                    eps * mu_vis / mu,
                    eps * mu_vis / mu_sim,
                    f"{cls} simulated {mu / mu_sim:.3g}x less viscous than asked (mu "
                    f"{mu:.3g} -> {mu_sim:.3g} Pa s): it flows up to {mu / mu_sim:.3g}x "
                    f"faster; {_REMEDY}",
                )
            )
    return out


def _pct(x: float) -> str:
    return f"{100 * x:.2g} %" if x < 10 else "more than 1000 %"


@dataclass(frozen=True)
class SubstepPlan:
    """Substeps per frame for a run and the context its material was mapped with."""

    substeps: int
    """Substeps per frame the solver runs."""
    ctx: SimContext
    """Context of the sim map (``dt``: the mapping substep; may be finer than the run's)."""
    sim: dict[str, float]
    """Simulation values (:func:`physical_to_sim` under ``ctx``)."""
    notes: list[str]
    """Warning lines for the terminal (the auto cap binding); empty when all is well."""
    violations: list[ClassViolation]
    """What still makes the material leave its class (only when the auto cap binds)."""


def _ctx(dx, frame_dt, n, density, length, gravity, yield_rule, scene=None) -> SimContext:
    return SimContext(
        dx=dx,
        dt=frame_dt / n,
        density=density,
        length=length,
        gravity=gravity,
        yield_rule=yield_rule,
        frame_dt=frame_dt,
        **(scene or {}),
    )


SCENE_KEYS = ("speed_met", "thickness", "duration", "visible_strain")
"""The :class:`SimContext` fields that describe what the scene shows (``scene=`` of
:func:`plan_substeps` and :func:`substeps_keeping_class`)."""


def substeps_keeping_class(
    params: MaterialParams,
    *,
    dx: float,
    frame_dt: float,
    length: float,
    gravity: float,
    start: int = 1,
    cap: int = MAX_AUTO_SUBSTEPS,
    yield_rule: str = "auto",
    scene: Mapping[str, Any] | None = None,
) -> int | None:
    """Smallest mapping substep count in ``[start, cap]`` that keeps the class; None above cap.

    Monotone in the count (a finer step raises every simulated stiffness and yield
    stress), so doubling then bisection finds it in O(log cap) maps.
    """
    rho = float(params.density)

    def ok(n: int) -> bool:
        ctx = _ctx(dx, frame_dt, n, rho, length, gravity, yield_rule, scene)
        sim = {k: float(v) for k, v in physical_to_sim(params, ctx).items()}
        return not class_violations(params, sim, ctx)

    lo = max(1, int(start))
    if ok(lo):
        return lo
    hi = lo
    while not ok(hi):
        if hi >= cap:
            return None
        lo, hi = hi, min(cap, hi * 2)
    while hi - lo > 1:  # ok(hi), not ok(lo)
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


def plan_substeps(
    params: MaterialParams,
    substeps: int | str,
    *,
    dx: float,
    frame_dt: float,
    length: float,
    gravity: float,
    cfl_substeps,
    yield_rule: str = "auto",
    cap: int = MAX_AUTO_SUBSTEPS,
    where: str = "sim.substeps",
    scene: Mapping[str, Any] | None = None,
) -> SubstepPlan:
    """Choose (``auto``) or check (a fixed count) the substeps of a run.

    ``scene``: what the scene shows (:data:`SCENE_KEYS`: the speed met, the slender
    thickness, the run's duration), from which the map knows which stiffness and
    viscosity can be seen (module docstring, "What can be seen").

    ``auto``: the budget is ``cap`` substeps per frame: map with ``dt = frame_dt / cap``
    (every visible value is simulated as asked when the budget allows it; invisible
    stiffness is compressed to just above the visible threshold), then run the CFL
    count of the mapped values (``cfl_substeps``: ``(sim_values_with_class, dx,
    frame_dt) -> int``: the solver's ``auto_substeps``, passed by the caller because
    materials/ must not import sim/). Where the budget forces a visible change, a
    note (one line, with the consequence) says so.

    A fixed count maps with ``dt = frame_dt / n``; one that makes the material leave its
    class raises :class:`~motionphysics.errors.UserInputError` (``"sim.substeps: with
    substeps 5 this metal is simulated with E = 1.6e+04 Pa ... ; use `substeps: auto`
    (N) or at least M"``); a visible change within the class is a note.
    """
    from motionphysics.errors import UserInputError

    rho = float(params.density)
    kw = dict(
        dx=dx,
        frame_dt=frame_dt,
        length=length,
        gravity=gravity,
        yield_rule=yield_rule,
        scene=scene,
    )

    def mapped(n: int):
        ctx = _ctx(dx, frame_dt, n, rho, length, gravity, yield_rule, scene)
        return ctx, {k: float(v) for k, v in physical_to_sim(params, ctx).items()}

    def auto_plan() -> SubstepPlan:
        n_map = max(1, int(cap))
        ctx, sim = mapped(n_map)
        left = class_violations(params, sim, ctx)
        notes: list[str] = []
        if left:
            notes.append(
                f"warning: {where}: auto is capped at {n_map} substeps per frame and at the "
                f"cap this {params.cls} {left[0].text}; {_REMEDY}"
            )
        else:
            notes += [f"warning: {where}: {c.text}" for c in visible_changes(params, sim, ctx)]
        run_n = int(cfl_substeps({"class": params.cls, **sim}, dx, frame_dt))
        return SubstepPlan(max(1, run_n), ctx, sim, notes, left)

    if substeps == "auto":
        return auto_plan()
    n = int(substeps)
    ctx, sim = mapped(n)
    bad = class_violations(params, sim, ctx)
    if not bad:
        changes = visible_changes(params, sim, ctx)
        auto_n = auto_plan().substeps if changes else 0  # (one auto plan, only when said)
        notes = [
            f"warning: {where}: with substeps {n} the {c.text.replace(_REMEDY, '')}"
            f"`substeps: auto` ({auto_n}) simulates it as asked"
            for c in changes
        ]
        return SubstepPlan(n, ctx, sim, notes, [])
    least = substeps_keeping_class(params, start=n, cap=cap, **kw)
    auto = auto_plan()
    need = f"at least {least}" if least is not None else f"more than {cap} (or a coarser sim.grid)"
    raise UserInputError(
        f"{where}: with substeps {n} this {params.cls} {bad[0].text}; use `substeps: auto` "
        f"({auto.substeps}) or {need}"
    )


# --- simulation values under their own names ------------------------------------------

SIM_QUANTITIES: dict[str, dict[str, tuple[str, str, str | None]]] = {
    # class -> sim key -> (display name, unit, the catalogue parameter it is the
    # simulated value of, or None when it is another quantity)
    "elastic": {"E": ("E", "Pa", "E"), "nu": ("nu", "1", "nu")},
    "plasticine": {
        "E": ("E", "Pa", "E"),
        "nu": ("nu", "1", "nu"),
        "tau_Y": ("tau_Y", "Pa", "tau_Y"),
    },
    "metal": {"E": ("E", "Pa", "E"), "nu": ("nu", "1", "nu"), "tau_Y": ("tau_Y", "Pa", "tau_Y")},
    "foam": {
        "E": ("E", "Pa", "E"),
        "nu": ("nu", "1", "nu"),
        "tau_Y": ("tau_Y", "Pa", "tau_Y"),
        "eta": ("eta", "1", "eta"),
    },
    "sand": {
        "theta_fric": ("theta_fric", "deg", "theta_fric"),
        "E": ("skeleton_E", "Pa", None),
        "nu": ("skeleton_nu", "1", None),
    },
    "newtonian": {"mu": ("mu", "Pa s", "mu"), "kappa": ("kappa", "Pa", "kappa")},
    "non_newtonian": {
        "eta": ("solver_consistency", "Pa s^n", None),
        "mu": ("unyielded_shear_modulus", "Pa", None),
        "kappa": ("kappa", "Pa", "kappa"),
        "tau_Y": ("uniaxial_yield_stress", "Pa", None),
        "n": ("n", "1", "n"),
    },
}
"""What each simulation value IS, per class. The non-Newtonian solver keys reuse the
catalogue's names for other quantities (sim ``mu`` is the unyielded shear modulus [Pa],
the catalogue's ``mu`` a viscosity [Pa s]; sim ``eta`` is the solver consistency
``2^((n+1)/2) K``; sim ``tau_Y`` the uniaxial von Mises yield stress ``sqrt(3)`` times the
catalogue's shear yield stress), so a reader must never see them paired by key."""


def sim_quantities(cls: str, sim_values: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Simulation values as a reader should see them, in a stable order.

    Each row: ``{"key": solver key, "name": display name, "unit", "value": float,
    "pairs_with": catalogue parameter or None}``. Summary, report and ``params.json``
    pair a row with a physical parameter only through ``pairs_with``; rows with None are
    listed under their own ``name`` (``unyielded_shear_modulus 1.4e5 Pa``).
    """
    table = SIM_QUANTITIES[normalise_class(cls)]
    rows = []
    for key, (name, unit, pair) in table.items():
        if key in sim_values:
            rows.append(
                {
                    "key": key,
                    "name": name,
                    "unit": unit,
                    "value": float(sim_values[key]),
                    "pairs_with": pair,
                }
            )
    return rows


def mapped_substitutions(
    params: MaterialParams,
    sim_values: Mapping[str, Any],
    rel_tol: float = 1e-6,
    ctx: SimContext | None = None,
) -> list[Any]:
    """:class:`~motionphysics.materials.catalog.Clamp` records (kind ``mapped to
    simulation``) for each parameter whose simulated value differs from the physical one
    (same quantity only: rows of :func:`sim_quantities` with ``pairs_with``).

    With ``ctx``: only the differences a viewer can see (:func:`visible_changes`); a
    change that cannot be seen is not a substitution (``params.json`` keeps both values
    under ``simulation``)."""
    from motionphysics.materials.catalog import Clamp

    shown = None
    if ctx is not None:
        shown = {c.parameter for c in visible_changes(params, sim_values, ctx)}
    out = []
    for row in sim_quantities(params.cls, sim_values):
        name = row["pairs_with"]
        if name is None or name not in params.values:
            continue
        if shown is not None and name not in shown:
            continue
        phys = float(params.values[name])
        if abs(row["value"] - phys) > rel_tol * max(abs(phys), 1e-30):
            out.append(Clamp(name, phys, row["value"], "mapped to simulation", "sim map"))
    return out
