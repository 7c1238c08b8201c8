"""The material catalogue: the seven classes, their parameters, SI units and ranges.

This is the ONE place in the code that holds the range tables: the paper's appendix
table ("Material parameters, their SI units, and value ranges for the seven simulated
material types (with sources)"), :data:`PAPER_MATERIALS`, and the extended table,
:data:`MATERIALS` (the default), which widens the paper's ranges where they leave out
what people name at the sizes they simulate (gels and jelly for elastic, oozing
viscosities for fluids...; each widening carries its reason in ``ParamSpec.note``; see
``_EXTENSIONS``). Everything else (the LLM prompt, the theta parameterisation, the
simulation map, the knowledge base checks, the median baseline) reads the ranges from
here. Which table bounds estimates is the run config's ``init.ranges`` (``extended`` or
``paper``; ``paper`` reproduces the paper's ablation); code asks :func:`ranges` /
:func:`materials` / :func:`spec` with ``table=...``, or sets it for a block with
:func:`use_ranges` (``table=None`` everywhere means the active table).

Values are physical, SI: Pa, Pa s, kg/m^3; ``theta_fric`` is in degrees; ``nu``,
``eta`` and ``n`` are unitless.

Deviations from the paper's table, on purpose:

* Non-Newtonian fluids also carry the Herschel-Bulkley power-law index ``n``
  (default 1 = Bingham, range 0.3-1.0). Rationale: shear-thinning pastes and food
  gels (toothpaste, ketchup, mayonnaise, yoghurt, cream) are fitted with n between
  roughly 0.3 and 0.7 and Bingham plastics with n = 1 (Chhabra & Richardson,
  *Non-Newtonian Flow and Applied Rheology*, 2nd ed., ch. 1, tables 1.2-1.3;
  Barnes, Hutton & Walters, *An Introduction to Rheology*, ch. 7); n > 1
  (shear-thickening, e.g. cornstarch) is not modelled by the return map.
* ``n`` is optional in answers (the paper's template does not ask for it); a
  missing ``n`` takes its default 1.0 and is not an error.
* ``mu`` of both fluid classes is a dynamic viscosity [Pa s] as in the table (the
  paper's list calls the non-Newtonian ``mu`` a shear modulus; its table gives Pa s).

This module must not scale parameters for the simulator; that is
:mod:`motionphysics.materials.simmap`.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from motionphysics.classes import MATERIAL_CLASSES
from motionphysics.errors import UserInputError

__all__ = [
    "SOURCES",
    "ParamSpec",
    "MaterialClass",
    "MATERIALS",
    "PAPER_MATERIALS",
    "RANGE_TABLES",
    "DEFAULT_RANGES",
    "active_ranges",
    "check_ranges",
    "materials",
    "ranges",
    "use_ranges",
    "DENSITY",
    "PARAM_NAMES",
    "MaterialParams",
    "Clamp",
    "CLAMP_KINDS",
    "MODEL_LIMIT_WORDS",
    "PHYSICAL_LIMITS",
    "RangeNote",
    "check_physical",
    "physical_problem",
    "range_notes",
    "normalise_class",
    "class_id",
    "param_names",
    "spec",
    "validate",
]

SOURCES: dict[str, str] = {
    "callister_materials": "Callister & Rethwisch, Materials Science and Engineering: An Introduction (Wiley)",
    "ashby_materials": "Ashby, Materials Selection in Mechanical Design (Butterworth-Heinemann)",
    "mitchell_soil": "Mitchell & Soga, Fundamentals of Soil Behavior (Wiley)",
    "gibson_ashby_foam": "Gibson & Ashby, Cellular Solids: Structure and Properties (Cambridge)",
    "crc_handbook": "CRC Handbook of Chemistry and Physics (CRC Press)",
    "wikipedia_mat": "Wikipedia, 'Densities of the elements' and 'Density' tables",
    "chhabra_rheology": "Chhabra & Richardson, Non-Newtonian Flow and Applied Rheology (Butterworth-Heinemann), ch. 1",
    "gel_mechanics": "Anseth, Bowman & Brannon-Peppas, Mechanical properties of hydrogels (Biomaterials 17, 1996); Smooth-On Ecoflex technical bulletins",
    "honey_viscosity": "Yanniotis, Skaltsi & Karaburnioti, Effect of moisture content on the viscosity of honey at different temperatures (J. Food Eng. 72, 2006); CRC Handbook",
}

Scale = Literal["log", "linear"]


@dataclass(frozen=True)
class ParamSpec:
    """One physical parameter of a material class.

    ``low``/``high`` are the inclusive handbook range in ``unit`` (SI). ``scale`` says
    how the range is explored (theta parameterisation, medians, the sim map):
    ``log`` for quantities spanning orders of magnitude, ``linear`` otherwise.
    """

    name: str
    unit: str
    low: float
    high: float
    scale: Scale
    source: str
    description: str
    default: float | None = None
    """Value used when an answer omits the parameter; None means it is required."""
    note: str = ""
    """Why the extended table widens the paper's range here (empty: the paper's range)."""

    def contains(self, value: float) -> bool:
        return self.low <= value <= self.high

    def clip(self, value: float) -> float:
        return min(max(value, self.low), self.high)

    def range_text(self) -> str:
        """``'1e+07 - 4e+11 Pa'``: the range as written in prompts and messages."""
        unit = "" if self.unit == "1" else f" {self.unit}"
        return f"{_fmt(self.low)} - {_fmt(self.high)}{unit}"


def _fmt(x: float) -> str:
    if x == 0:
        return "0"
    if 1e-2 <= abs(x) < 1e3:
        return f"{x:g}"
    mant, exp = f"{x:.2e}".split("e")
    mant = mant.rstrip("0").rstrip(".")
    return f"{mant}e{int(exp)}"


@dataclass(frozen=True)
class MaterialClass:
    """A material class: its parameters (paper's names), constitutive model, aliases."""

    name: str
    label: str
    params: tuple[ParamSpec, ...]
    elastic_law: str
    return_mapping: str
    aliases: tuple[str, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def param(self, name: str) -> ParamSpec:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def id(self) -> int:
        return MATERIAL_CLASSES.index(self.name)


MODEL_LIMITS: dict[str, str] = {
    "foam": (
        "the foam model is elastic-viscoplastic (StVK-Hencky with a viscously regularised "
        "von Mises return map): below its yield stress it springs back at once, above it "
        "the crushed part stays crushed; it has no viscoelastic memory, so a foam that "
        "'slowly recovers its shape' (memory foam) cannot be simulated as such: it either "
        "bounces back or stays dented"
    ),
    "sand": (
        "the sand model is Drucker-Prager plasticity without cohesion: grains stand in a "
        "heap up to their friction angle, but nothing holds them together, so a block or "
        "a sandcastle that 'holds together' or 'keeps its shape' slumps into a heap when "
        "it falls (wet sand only piles steeper); for a lump that holds together, give "
        "material.class: plasticine"
    ),
}
"""What a class's constitutive model cannot do that words may ask of it (the kb warns
when a prompt asks for it, :data:`MODEL_LIMIT_WORDS`; README, "What is simulated")."""

_NOT = r"(?<!\bnot )(?<!n't )(?<!\bnever )"
MODEL_LIMIT_WORDS: dict[str, str] = {
    "foam": (
        r"\brecover|slowly\s+(returns?|regains?|springs?|comes?)|back\s+to\s+(its\s+)?"
        r"(original\s+)?shape|regains?\s+(its\s+)?shape"
    ),
    "sand": (
        _NOT + r"\b(holds?|holding|keeps?|keeping|retains?|retaining)\s+"
        r"(together|(its|their)\s+(shape|form))"
        r"|" + _NOT + r"\b(stays?|staying|remains?|remaining)\s+"
        r"(together|intact|in\s+one\s+piece|whole)"
    ),
}
"""Case-insensitive patterns of the words asking a class for what :data:`MODEL_LIMITS`
says it cannot do: a slow recovery of foam; sand that holds together (a negated "does
not hold together" asks for nothing the model lacks)."""


def _E(low, high, source):
    return ParamSpec("E", "Pa", low, high, "log", source, "Young's modulus")


def _nu(low, high, source):
    return ParamSpec("nu", "1", low, high, "linear", source, "Poisson's ratio")


def _tau(low, high, source):
    return ParamSpec("tau_Y", "Pa", low, high, "log", source, "yield stress")


def _eta(low, high, source):
    return ParamSpec("eta", "1", low, high, "log", source, "plastic viscosity")


_KAPPA = ParamSpec("kappa", "Pa", 1e9, 5e9, "log", "crc_handbook", "bulk modulus")

PAPER_MATERIALS: dict[str, MaterialClass] = {
    "elastic": MaterialClass(
        "elastic",
        "Elastic",
        (_E(1e7, 4e11, "callister_materials"), _nu(0.1, 0.5, "callister_materials")),
        "fixed corotated",
        "identity",
        ("elastic", "elastic solid", "elastic material", "rubber", "rubbery", "jelly", "soft body"),
    ),
    "plasticine": MaterialClass(
        "plasticine",
        "Plasticine",
        (
            _E(1e6, 5e6, "ashby_materials"),
            _nu(0.3, 0.4, "ashby_materials"),
            _tau(5e3, 2e4, "ashby_materials"),
        ),
        "StVK",
        "von Mises with damage",
        (
            "plasticine",
            "clay",
            "modelling clay",
            "modeling clay",
            "play-doh",
            "playdoh",
            "plastically deformable",
        ),
    ),
    "metal": MaterialClass(
        "metal",
        "Metal",
        (
            _E(4.5e10, 4.0e11, "callister_materials"),
            _nu(0.25, 0.35, "callister_materials"),
            _tau(1e7, 2e9, "callister_materials"),
        ),
        "StVK",
        "von Mises",
        ("metal", "metallic", "metals", "steel", "iron"),
    ),
    "foam": MaterialClass(
        "foam",
        "Foam",
        (
            _E(1e3, 1e7, "gibson_ashby_foam"),
            _nu(0.0, 0.3, "gibson_ashby_foam"),
            _tau(1e4, 1e6, "gibson_ashby_foam"),
            _eta(0.1, 1.0, "gibson_ashby_foam"),
        ),
        "StVK",
        "viscoplastic",
        ("foam", "foams", "sponge", "spongy", "viscoplastic foam", "cellular solid"),
    ),
    "sand": MaterialClass(
        "sand",
        "Sand",
        (ParamSpec("theta_fric", "deg", 27.0, 45.0, "linear", "mitchell_soil", "friction angle"),),
        "StVK",
        "Drucker-Prager",
        ("sand", "granular", "granular material", "soil", "sandy", "powder"),
    ),
    "newtonian": MaterialClass(
        "newtonian",
        "Newtonian fluid",
        (ParamSpec("mu", "Pa s", 1e-3, 10.0, "log", "crc_handbook", "dynamic viscosity"), _KAPPA),
        "compressible neo-Hookean",
        "identity",
        (
            "newtonian",
            "newtonian fluid",
            "newtonian liquid",
            "fluid",
            "liquid",
            "water",
            "viscous fluid",
            "viscous liquid",
        ),
    ),
    "non_newtonian": MaterialClass(
        "non_newtonian",
        "Non-Newtonian fluid",
        (
            ParamSpec("mu", "Pa s", 1e-3, 1e3, "log", "crc_handbook", "dynamic viscosity"),
            _KAPPA,
            _tau(1.0, 2e3, "ashby_materials"),
            _eta(0.1, 1.0, "ashby_materials"),
            ParamSpec(
                "n",
                "1",
                0.3,
                1.0,
                "linear",
                "chhabra_rheology",
                "Herschel-Bulkley power-law index (1 = Bingham)",
                default=1.0,
            ),
        ),
        "StVK",
        "Herschel-Bulkley",
        (
            "non_newtonian",
            "non-newtonian",
            "non newtonian",
            "nonnewtonian",
            "non-newtonian fluid",
            "non newtonian fluid",
            "non-newtonian liquid",
            "herschel-bulkley",
            "herschel bulkley",
            "bingham",
            "bingham plastic",
            "viscoplastic fluid",
            "yield-stress fluid",
            "shear-thinning fluid",
            "paste",
        ),
    ),
}
assert tuple(PAPER_MATERIALS) == MATERIAL_CLASSES  # ids in the kernels follow this order
# --- the extended table (the default) ---------------------------------------------------
# The paper's ranges bound what an estimate may say. Where they leave out what people
# name at the sizes they simulate (tens of centimetres), the extended table widens them;
# every widening keeps the paper's range inside it and says why (``ParamSpec.note``).
# ``init.ranges: paper`` (run config) / ``--ranges paper`` (init) uses the paper's table.
_EXTENSIONS: dict[tuple[str, str], tuple[float, float, str, str]] = {
    ("elastic", "E"): (
        1e3,
        4e11,
        "gel_mechanics",
        "gels: jelly and gelatin desserts 1-10 kPa, soft silicone (Ecoflex) 50-100 kPa, tofu "
        "and flesh 10-500 kPa, rubber 1-10 MPa; the paper's floor (1e7 Pa) makes every one "
        "of them as stiff as a tyre, and a 'wobbly jelly' bounces like rubber",
    ),
    ("plasticine", "E"): (
        1e5,
        1e8,
        "ashby_materials",
        "soft clays and doughs (0.1-1 MPa) to cold butter (~30 MPa) and wax (~100 MPa)",
    ),
    ("plasticine", "tau_Y"): (
        1e3,
        1e6,
        "ashby_materials",
        "soft clay and dough yield at about 1 kPa (a 30 cm lump then slumps under its own "
        "weight, rho g L ~ 5 kPa), cold butter at ~50 kPa, wax near 1 MPa",
    ),
    ("metal", "E"): (
        1e10,
        4.0e11,
        "callister_materials",
        "lead (14 GPa) and its alloys lie below the paper's floor of 45 GPa",
    ),
    ("metal", "nu"): (
        0.25,
        0.45,
        "callister_materials",
        "gold 0.42, lead 0.44, platinum 0.39",
    ),
    ("metal", "tau_Y"): (
        1e6,
        2e9,
        "callister_materials",
        "annealed lead, tin and solder yield at a few MPa",
    ),
    ("foam", "E"): (
        1e3,
        1e8,
        "gibson_ashby_foam",
        "cork (~20 MPa) and rigid polymer foams (up to ~100 MPa)",
    ),
    ("foam", "tau_Y"): (
        1e3,
        1e6,
        "gibson_ashby_foam",
        "the plateau stress of soft polyurethane foams is 1-5 kPa",
    ),
    ("sand", "theta_fric"): (
        20.0,
        50.0,
        "mitchell_soil",
        "glass beads and marbles repose at 21-24 degrees; moist and cohesive granular "
        "matter (wet sand, flour, kinetic sand) stands at up to about 50",
    ),
    ("newtonian", "mu"): (
        1e-4,
        1e4,
        "honey_viscosity",
        "at the sizes people simulate a Newtonian fluid only oozes (viscosity beats inertia "
        "over its own size L: Reynolds number rho sqrt(g L) L / mu below 1) when mu exceeds "
        "rho sqrt(g L) L, about 700 Pa s for L = 0.3 m; measured here, no viscosity up to "
        "the paper's ceiling of 10 Pa s oozed at tens of centimetres (421 of 421 simulated "
        "clips splashed). Honey is 2-10 Pa s at room temperature and about 100 Pa s cold, "
        "molasses and tar far more; the floor admits solvents and fuels (0.3-0.6 mPa s)",
    ),
    ("non_newtonian", "mu"): (
        1e-3,
        1e4,
        "chhabra_rheology",
        "polymer melts, caulks and stiff pastes (1e2-1e4 Pa s); the same ooze scale as for "
        "Newtonian fluids",
    ),
    ("non_newtonian", "tau_Y"): (
        1.0,
        1e4,
        "chhabra_rheology",
        "stiff pastes (caulk, fresh mortar, peanut butter) yield at 1-10 kPa",
    ),
    ("non_newtonian", "n"): (
        0.2,
        1.0,
        "chhabra_rheology",
        "ketchup and other strongly shear-thinning sauces are fitted with n of 0.2-0.3",
    ),
}


def _extend(mc: MaterialClass) -> MaterialClass:
    params = []
    for ps in mc.params:
        ext = _EXTENSIONS.get((mc.name, ps.name))
        if ext is None:
            params.append(ps)
            continue
        low, high, source, why = ext
        assert low <= ps.low and high >= ps.high, (mc.name, ps.name)  # the paper's inside
        params.append(replace(ps, low=low, high=high, source=source, note=why))
    return replace(mc, params=tuple(params))


MATERIALS: dict[str, MaterialClass] = {name: _extend(mc) for name, mc in PAPER_MATERIALS.items()}
"""The catalogue's classes with the extended ranges (the default table); the paper's
table is :data:`PAPER_MATERIALS`, both through :func:`ranges` / :func:`materials`."""

RANGE_TABLES: tuple[str, ...] = ("extended", "paper")
"""The range tables: ``extended`` (default, :data:`MATERIALS`) and ``paper`` (the paper's
appendix table exactly, :data:`PAPER_MATERIALS`, for its ablation)."""
DEFAULT_RANGES = "extended"
_TABLES = {"extended": MATERIALS, "paper": PAPER_MATERIALS}
_ACTIVE: ContextVar[str] = ContextVar("motionphysics_ranges", default=DEFAULT_RANGES)


def check_ranges(table: Any, where: str = "init.ranges") -> str:
    """``table`` if it names a range table, else :class:`UserInputError` (one line)."""
    if table not in _TABLES:
        raise UserInputError(f"{where}: expected one of {', '.join(RANGE_TABLES)}, got {table!r}")
    return table


def active_ranges() -> str:
    """The range table used where none is named: ``extended``, or what the innermost
    :func:`use_ranges` set (a run sets its config's ``init.ranges``)."""
    return _ACTIVE.get()


@contextmanager
def use_ranges(table: str | None):
    """Within the block, estimates, clamps, range notes, medians and the LLM prompt use
    ``table`` (None: leave the active table as it is)."""
    if table is None:
        yield active_ranges()
        return
    token = _ACTIVE.set(check_ranges(table))
    try:
        yield table
    finally:
        _ACTIVE.reset(token)


def materials(table: str | None = None) -> dict[str, MaterialClass]:
    """The classes of a range table (None: the active one, see :func:`active_ranges`)."""
    return _TABLES[check_ranges(table if table is not None else _ACTIVE.get())]


def ranges(cls: str, table: str | None = None) -> MaterialClass:
    """Class ``cls`` (aliases accepted) in range table ``table`` (``"extended"`` or
    ``"paper"``; None: the active one): ``ranges("elastic", "paper").param("E").low`` is
    1e7, ``ranges("elastic").param("E").low`` 1e3."""
    return materials(table)[normalise_class(cls)]


DENSITY = ParamSpec("density", "kg/m^3", 10.0, 2.3e4, "log", "crc_handbook", "mass density")
"""Common to all classes (appendix table, 'Common' row; CRC and Wikipedia)."""

PARAM_NAMES: tuple[str, ...] = ("E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n")
"""Every physical parameter name used by some class (the per-particle arrays)."""


def _norm_key(text: str) -> str:
    s = text.strip().lower()
    for ch in "-_/":
        s = s.replace(ch, " ")
    return " ".join(s.split())


_ALIAS_TO_CLASS: dict[str, str] = {}
for _c in MATERIALS.values():
    for _a in (_c.name, _c.label, *_c.aliases):
        _ALIAS_TO_CLASS.setdefault(_norm_key(_a), _c.name)
# Spellings seen in LLM answers that reduce to an ambiguous key above.
_ALIAS_TO_CLASS.update(
    {
        "non newtonian": "non_newtonian",
        "non newtonian fluid": "non_newtonian",
        "nonnewtonian fluid": "non_newtonian",
        "elastic body": "elastic",
        "metal solid": "metal",
        "granular sand": "sand",
    }
)


def normalise_class(name: Any, field: str = "class") -> str:
    """Map an answer's class name ("Metal", "Newtonian fluid", "non-newtonian") to its id.

    Raises :class:`UserInputError` naming ``field`` and the accepted classes.
    """
    if not isinstance(name, str) or not name.strip():
        raise UserInputError(
            f"{field}: expected a material class name (one of {', '.join(MATERIAL_CLASSES)}), got {name!r}"
        )
    key = _norm_key(name)
    if key in _ALIAS_TO_CLASS:
        return _ALIAS_TO_CLASS[key]
    # "Metal (steel)", "elastic material type": strip trailing qualifiers.
    for cut in ("(", ",", ";"):
        if cut in key:
            head = key.split(cut)[0].strip()
            if head in _ALIAS_TO_CLASS:
                return _ALIAS_TO_CLASS[head]
    if key.endswith(" material") and key[: -len(" material")] in _ALIAS_TO_CLASS:
        return _ALIAS_TO_CLASS[key[: -len(" material")]]
    raise UserInputError(
        f"{field}: unknown material class {name!r}; expected one of {', '.join(MATERIAL_CLASSES)}"
    )


def class_id(cls: str) -> int:
    """Integer id of a class (``config.MATERIAL_CLASSES`` order, used by the kernels)."""
    return MATERIAL_CLASSES.index(normalise_class(cls))


def param_names(cls: str) -> tuple[str, ...]:
    """The physical parameters of a class, density excluded, in table order."""
    return MATERIALS[normalise_class(cls)].names


def spec(cls: str, name: str, table: str | None = None) -> ParamSpec:
    """The :class:`ParamSpec` of ``name`` (``density`` included) for class ``cls`` in range
    table ``table`` (None: the active one, :func:`active_ranges`)."""
    if name == "density":
        return DENSITY
    return ranges(cls, table).param(name)


@dataclass(frozen=True)
class MaterialParams:
    """A material: class id, density [kg/m^3] and the class's physical parameters (SI).

    ``values`` maps parameter names (``MATERIALS[cls].names``) to python floats after
    :func:`validate`; the optimiser may also build one with torch tensors (scalars or
    per-particle ``[P]``) to push through the sim map.
    """

    cls: str
    density: Any
    values: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """``{"class": ..., "density": ..., <param>: ...}`` with python floats."""
        out: dict[str, Any] = {"class": self.cls, "density": _as_float(self.density)}
        for k in MATERIALS[self.cls].names:
            if k in self.values:
                out[k] = _as_float(self.values[k])
        return out


def _as_float(v: Any) -> Any:
    try:
        return float(v)
    except (TypeError, ValueError):
        return v


CLAMP_KINDS = ("clamped", "range floor", "mapped to simulation")
"""What a substitution is: ``clamped`` (an estimate moved into its handbook range),
``range floor`` (an estimate whose real value lies below the class's range, set to the
floor by the estimator itself, e.g. the kb's rubber), ``mapped to simulation`` (the
simulation uses another value than the physical one; :mod:`~motionphysics.materials.simmap`)."""


@dataclass(frozen=True)
class Clamp:
    """A substituted value: which field, the value given, the value used, and what kind.

    ``kind`` is one of :data:`CLAMP_KINDS`; ``source`` says whose value it was
    (``kb``, ``llm``, ``median``, ``config``...), empty when unknown.
    """

    field: str
    original: float
    clamped: float
    kind: str = "clamped"
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        out = {
            "field": self.field,
            "original": self.original,
            "clamped": self.clamped,
            "kind": self.kind,
        }
        if self.source:
            out["source"] = self.source
        return out

    def text(self, unit: str = "") -> str:
        """``E: 1e+06 -> 1e+07 Pa (clamped, kb)``: one line for summaries and warnings."""
        u = f" {unit}" if unit and unit != "1" else ""
        who = f", {self.source}" if self.source else ""
        return f"{self.field}: {self.original:.4g} -> {self.clamped:.4g}{u} ({self.kind}{who})"


# --- physical validity ------------------------------------------------------------------
# Not the handbook ranges (those bound estimates) but what no material can have: a value
# outside these is a mistake wherever it comes from (config, params file, LLM answer).
# (low, high, low_open, high_open, what is expected)
PHYSICAL_LIMITS: dict[str, tuple[float, float, bool, bool, str]] = {
    "density": (0.0, math.inf, True, True, "a mass density > 0 kg/m^3"),
    "E": (0.0, math.inf, True, True, "a Young's modulus > 0 Pa"),
    "nu": (-1.0, 0.5, True, False, "a Poisson's ratio with -1 < nu <= 0.5"),
    "tau_Y": (0.0, math.inf, True, True, "a yield stress > 0 Pa"),
    "eta": (0.0, math.inf, True, True, "a plastic viscosity > 0"),
    "theta_fric": (0.0, 90.0, True, True, "a friction angle between 0 and 90 degrees"),
    "mu": (0.0, math.inf, True, True, "a viscosity > 0 Pa s"),
    "kappa": (0.0, math.inf, True, True, "a bulk modulus > 0 Pa"),
    "n": (0.0, math.inf, True, True, "a power-law index > 0"),
}
"""``nu = 0.5`` is the incompressible limit (rubber), admitted and simulated as 0.49;
``nu <= -1`` or ``> 0.5`` would make the bulk or shear modulus negative."""


def physical_problem(name: str, value: Any) -> str | None:
    """What is expected when ``value`` is impossible for parameter ``name``, else None."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return "a number"
    x = float(value)
    if not math.isfinite(x):
        return "a finite number"
    lim = PHYSICAL_LIMITS.get(name)
    if lim is None:
        return None
    lo, hi, lo_open, hi_open, what = lim
    if (x < lo or (lo_open and x == lo)) or (x > hi or (hi_open and x == hi)):
        return what
    return None


def check_physical(name: str, value: Any, where: str) -> float:
    """``float(value)`` or :class:`UserInputError` ``"{where}: got -5; expected ..."``."""
    problem = physical_problem(name, value)
    if problem is not None:
        raise UserInputError(
            f"{where}: got {value!r}; expected {problem} (physically impossible)"
            if problem not in ("a number", "a finite number")
            else f"{where}: got {value!r}; expected {problem}"
        )
    return float(value)


@dataclass(frozen=True)
class RangeNote:
    """A value used as written although it lies outside its handbook range."""

    field: str
    value: float
    low: float
    high: float
    unit: str
    cls: str

    def text(self, origin: str = "material") -> str:
        side = "below" if self.value < self.low else "above"
        u = "" if self.unit == "1" else f" {self.unit}"
        return (
            f"warning: {origin}.{self.field} = {self.value:.4g}{u} is {side} the handbook range "
            f"of {self.cls} ({_fmt(self.low)} - {_fmt(self.high)}{u}); used as written"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "field": self.field,
            "value": self.value,
            "range": [self.low, self.high],
            "unit": self.unit,
        }


def range_notes(
    params: MaterialParams, fields: Any = None, table: str | None = None
) -> list[RangeNote]:
    """The values of ``params`` (only ``fields`` when given) outside their handbook range
    (of range table ``table``; None: the active one)."""
    out = []
    items = {"density": params.density, **params.values}
    for name, value in items.items():
        if fields is not None and name not in fields:
            continue
        ps = spec(params.cls, name, table)
        v = float(value)
        if not ps.contains(v):
            out.append(RangeNote(name, v, ps.low, ps.high, ps.unit, params.cls))
    return out


def _number(value: Any, where: str, name: str = "") -> float:
    return check_physical(name, value, where)


def validate(
    cls: str,
    values: Mapping[str, Any],
    density: Any = None,
    on_out_of_range: Literal["clamp", "error", "keep"] = "clamp",
    origin: str = "material",
    source: str = "",
    table: str | None = None,
) -> tuple[MaterialParams, list[Clamp]]:
    """Check a material against the catalogue.

    ``cls`` is normalised (aliases accepted). ``values`` holds the class's parameters
    (and may hold ``density`` when ``density`` is None). Unknown class, missing or
    extra parameters and non-numbers / non-finite values always raise
    :class:`UserInputError` (one line, prefixed by ``origin``), and so do physically
    impossible values (:data:`PHYSICAL_LIMITS`: a negative modulus, ``nu > 0.5``...)
    in every mode. Values outside their handbook range raise with
    ``on_out_of_range='error'``, are clamped to the range with ``'clamp'`` (what
    estimates get) and recorded as :class:`Clamp` (kind ``clamped``, ``source``), or
    are kept as given with ``'keep'`` (what a person wrote; list them with
    :func:`range_notes` to warn). A missing parameter with a default (``n``) takes
    the default. ``table``: the range table (``extended``, ``paper``; None: the active
    one, :func:`active_ranges`).

    Returns ``(MaterialParams with python floats, clamps)``.
    """
    if on_out_of_range not in ("clamp", "error", "keep"):
        raise ValueError(
            f"on_out_of_range must be 'clamp', 'error' or 'keep', got {on_out_of_range!r}"
        )
    name = normalise_class(cls, field=f"{origin}.class")
    mc = ranges(name, table)
    vals = dict(values)
    if density is None:
        density = vals.pop("density", None)
    elif "density" in vals:
        raise UserInputError(f"{origin}: density given twice")
    extra = sorted(set(vals) - set(mc.names))
    if extra:
        raise UserInputError(
            f"{origin}: parameter(s) {', '.join(extra)} do not belong to class {name} "
            f"(expected {', '.join(mc.names)})"
        )
    if density is None:
        raise UserInputError(
            f"{origin}.density: missing (expected kg/m^3 in {DENSITY.range_text()})"
        )
    clamps: list[Clamp] = []
    out: dict[str, float] = {}

    def check(ps: ParamSpec, raw: Any) -> float:
        where = f"{origin}.{ps.name}"
        x = _number(raw, where, ps.name)
        if ps.contains(x) or on_out_of_range == "keep":
            return x
        if on_out_of_range == "error":
            raise UserInputError(
                f"{where}: {x:g} is outside the range of class {name} ({ps.range_text()})"
            )
        y = ps.clip(x)
        clamps.append(Clamp(ps.name, x, y, "clamped", source))
        return y

    rho = check(DENSITY, density)
    for ps in mc.params:
        if ps.name not in vals or vals[ps.name] is None:
            if ps.default is not None:
                out[ps.name] = ps.default
                continue
            raise UserInputError(
                f"{origin}.{ps.name}: missing for class {name} (expected {ps.description} "
                f"in {ps.range_text()})"
            )
        out[ps.name] = check(ps, vals[ps.name])
    return MaterialParams(name, rho, out), clamps
