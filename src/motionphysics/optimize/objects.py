"""Several objects optimised together: one parameter vector per object in one theta.

``run`` with a prior and ``fit`` optimise a scene of several objects (``objects:`` or
``scene.split``) through this module; one object goes through :mod:`.fit` unchanged.

- Which parameters: ``optimize.params`` as a list applies to every object; a mapping by
  object name (``{duck: [E], block: [E]}``) gives each its own list, and an object it
  leaves out keeps its material. Unset: each object's class default (``fit``: all but
  :data:`~motionphysics.optimize.fit.FIT_DEFAULT_FIXED`; ``run``: all).
- Names: the leaves of theta are ``OBJECT.PARAM`` (``duck.E``): the keys of
  ``optimize.lr_per_param``, of ``grad_norm`` in ``log.jsonl`` and of ``optimised`` in
  params.json. Values are reported by object: each record's ``params`` and
  ``sim_params`` are ``{object: {name: value}}`` (density included), in object order.
- The map: :class:`ObjectsThetaMap` stacks each object's catalogue
  ``Parameterisation`` (its class's handbook ranges); each object's physical values go
  through that object's sim map context (:meth:`Assembly.to_sim_objects`) into the
  differentiable :class:`~motionphysics.assembly.ObjectsSimulator`, which spreads them
  over the object's particles, so each object's gradient comes from the motion of the
  whole scene (contact included).
- A prior that observes states (``--prior motion``) sees each object apart:
  :class:`PerObjectLoss` gives every object the configured losses built with its own
  phrase (:func:`object_prompt`) and a view of the prior that knows that object's rest
  state, observes that object's particles only, and sums the objects' losses (an object
  whose parameters are not optimised is observed when the prompt has a phrase for it:
  its motion depends on the others' through contact). A prior
  that observes frames sees the whole render with the whole prompt (every object is in
  the picture and the prompt describes them all).

This module does no file I/O; :mod:`.fit` and :mod:`.refine` write the run directory.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.io.object_params import SEP, leaf
from motionphysics.losses.base import Loss, LossContext, Prediction
from motionphysics.optimize.problem import ParamSpec, Problem, _summary

__all__ = [
    "SEP",
    "ObjectsProblem",
    "ObjectsThetaMap",
    "PerObjectLoss",
    "build_objects_problem",
    "final_scene_material",
    "initial_record",
    "object_prompt",
    "objects_optimised",
    "side_by_side",
]


# --- which parameters -------------------------------------------------------------------
def objects_optimised(cfg, objects, *, for_fit: bool = False) -> dict[str, list[str]]:
    """``{object: [names]}`` of the objects whose parameters are optimised (object
    order; an object a mapping leaves out is absent). ``objects``: the assembly's
    :class:`~motionphysics.assembly.ObjectPart` s. ``for_fit``: an object without a list
    gets ``fit``'s default (``fit.FIT_DEFAULT_FIXED`` left out), else all its class's."""
    from motionphysics.optimize import fit as fit_module
    from motionphysics.optimize.fit import optimised_names

    fixed = tuple(getattr(fit_module, "FIT_DEFAULT_FIXED", ())) if for_fit else ()
    params = cfg.optimize.params
    names = [o.name for o in objects]
    if isinstance(params, Mapping):
        unknown = [k for k in params if k not in names]
        if unknown:  # (scene.split names its parts only at assembly)
            raise UserInputError(
                f"optimize.params: {', '.join(unknown)} not an object of this scene; expected "
                f"names among {', '.join(names)}"
            )
    out: dict[str, list[str]] = {}
    for o in objects:
        if isinstance(params, Mapping):
            if o.name not in params:
                continue
            own = list(params[o.name])
        else:
            own = None if params is None else list(params)
        one = cfg.model_copy(
            update={"optimize": cfg.optimize.model_copy(update={"params": own, "per_particle": []})}
        )
        try:
            out[o.name] = optimised_names(one, o.material.cls, *((fixed,) if fixed else ()))
        except UserInputError as err:
            text = str(err)
            if text.startswith("optimize.params:"):
                text = f"optimize.params.{o.name}:" + text[len("optimize.params:") :]
            raise UserInputError(text) from None
    return out


# --- theta --------------------------------------------------------------------------------
class ObjectsThetaMap:
    """theta <-> physical values of several objects: each object's catalogue
    ``Parameterisation`` over its names, stacked in object order.

    ``names``: ``OBJECT.PARAM`` leaf names. ``to_theta({leaf: value}) -> [k]``;
    ``from_theta(theta [k, ...]) -> {leaf: [...]}`` (differentiable)."""

    def __init__(self, per_object: list[tuple[str, str, list[str]]], ranges=None):
        from motionphysics.materials.theta import Parameterisation

        ranges = ranges or {}
        self.maps = [
            (obj, Parameterisation(cls, names, ranges=ranges.get(obj)))
            for obj, cls, names in per_object
        ]
        self.names = [leaf(obj, n) for obj, pm in self.maps for n in pm.names]

    def to_theta(self, values: Mapping[str, Any]) -> Tensor:
        parts = [pm.to_theta({n: values[leaf(obj, n)] for n in pm.names}) for obj, pm in self.maps]
        return torch.cat(parts)

    def from_theta(self, theta: Tensor) -> dict[str, Tensor]:
        out: dict[str, Tensor] = {}
        i = 0
        for obj, pm in self.maps:
            k = len(pm.names)
            for n, v in pm.from_theta(theta[i : i + k]).items():
                out[leaf(obj, n)] = v
            i += k
        return out


@dataclass
class ObjectsProblem(Problem):
    """A :class:`Problem` over several objects: ``to_sim`` returns one simulation dict
    per object (what :class:`~motionphysics.assembly.ObjectsSimulator` takes) and
    :meth:`report` groups the values by object."""

    objects: tuple[str, ...] = ()
    """Object names, in the simulator's order."""
    classes: tuple[str, ...] = ()
    """Each object's class (same order)."""

    def per_object(self, phys: Mapping[str, Any]) -> list[dict[str, Any]]:
        """``{leaf: value}`` -> one ``{name: value}`` per object (object order)."""
        out: list[dict[str, Any]] = [{} for _ in self.objects]
        index = {o: i for i, o in enumerate(self.objects)}
        for key, v in phys.items():
            obj, _, name = key.rpartition(SEP)
            out[index[obj]][name] = v
        return out

    def report(self, theta: dict[str, Tensor]) -> tuple[dict, dict]:
        with torch.no_grad():
            phys = self.all_physical(theta)
            sims = self.to_sim(phys)
        per = self.per_object(phys)
        out_p = {
            o: {k: _summary(p[k]) for k in _ordered(p)}
            for o, p in zip(self.objects, per, strict=True)
        }
        out_s = {
            o: {k: _summary(v) for k, v in s.items()}
            for o, s in zip(self.objects, sims, strict=True)
        }
        return out_p, out_s


def _ordered(values: Mapping[str, Any]) -> list[str]:
    """density first, then the class's names in their given order."""
    return (["density"] if "density" in values else []) + [k for k in values if k != "density"]


def build_objects_problem(parts, loss, optimised: dict[str, list[str]]) -> ObjectsProblem:
    """The :class:`ObjectsProblem` of an assembly of several objects: theta of
    ``optimised`` (``{object: [names]}``), every other value fixed at the assembly's."""
    from motionphysics.materials.catalog import spec

    if not optimised:
        raise UserInputError("optimize.params: names no object's parameters to optimise")
    objs = list(parts.objects)
    from motionphysics.optimize.fit import start_ranges

    per, initial, fixed, specs = [], {}, {}, {}
    ranges, notes = {}, []
    for o in objs:
        m = o.material
        start = {"density": float(m.density), **{k: float(v) for k, v in m.values.items()}}
        names = optimised.get(o.name, [])
        if names:
            per.append((o.name, m.cls, names))
            wide, lines = start_ranges(m.cls, names, start, lambda n, o=o: leaf(o.name, n))
            ranges[o.name] = wide
            notes += lines
        for k, v in start.items():
            if k in names:
                initial[leaf(o.name, k)] = v
                ps = spec(m.cls, k)
                lo, hi = ranges[o.name].get(k, (float(ps.low), float(ps.high)))
                specs[leaf(o.name, k)] = ParamSpec(leaf(o.name, k), ps.unit, lo, hi, ps.scale)
            else:
                fixed[leaf(o.name, k)] = v
    cfg = parts.cfg
    problem = ObjectsProblem(
        theta_map=ObjectsThetaMap(per, ranges),
        range_notes=notes,
        initial=initial,
        fixed=fixed,
        to_sim=lambda phys: parts.to_sim_objects(problem.per_object(phys)),
        simulator=parts.simulator(int(cfg.sim.frames), per_object=True),
        loss=loss,
        renderer=parts.renderer() if loss.needs_render else None,
        specs=specs,
        objects=tuple(o.name for o in objs),
        classes=tuple(o.material.cls for o in objs),
    )
    return problem


def final_scene_material(problem: ObjectsProblem, parts, theta: dict[str, Tensor]):
    """The :class:`~motionphysics.assembly.SceneMaterial` at ``theta`` (each object's
    MaterialParams with its fitted values; the others as they were)."""
    with torch.no_grad():
        per = problem.per_object(problem.all_physical(theta))
    mats = []
    for o, values in zip(parts.objects, per, strict=True):
        m = o.material
        vals = {k: float(torch.as_tensor(values[k]).double()) for k in m.values}
        mats.append(type(m)(m.cls, float(torch.as_tensor(values["density"]).double()), vals))
    return parts.with_materials(mats).material


def initial_record(material, resolution) -> dict[str, Any]:
    """params.json's ``initial`` of a scene of several objects: each object's starting
    physical and simulation values, and the scene's substeps."""
    return {
        "objects": {
            o.name: {
                "params": {k: float(v) for k, v in o.material.values.items()},
                "density": float(o.material.density),
                "sim": {k: float(v) for k, v in o.resolution.values.items()},
            }
            for o in material.objects
        },
        "substeps": int(resolution.substeps),
    }


def side_by_side(problem: ObjectsProblem, start, final) -> dict[str, dict[str, Any]]:
    """``{object: {name: {"initial", "final", "unit", "optimised"}}}`` (run's
    params.json ``optimise.parameters``)."""
    out: dict[str, dict[str, Any]] = {}
    optimised = set(problem.theta_map.names)
    for o0, o1 in zip(start.objects, final.objects, strict=True):
        m0, m1 = o0.material, o1.material
        rows = {}
        for name, v0 in {"density": m0.density, **m0.values}.items():
            v1 = m1.density if name == "density" else m1.values.get(name, v0)
            ps = problem.specs.get(leaf(o0.name, name))
            rows[name] = {
                "initial": float(v0),
                "final": float(v1),
                "unit": ps.unit if ps is not None else None,
                "optimised": leaf(o0.name, name) in optimised,
            }
        out[o0.name] = rows
    return out


# --- each object's phrase -----------------------------------------------------------------
_CLAUSE_SPLIT = re.compile(r"[,;.!?]|\b(?:and|while|whereas|but|then)\b", re.IGNORECASE)


def _names_in(text: str, forms: list[list[str]]) -> bool:
    from motionphysics.init.kb import tokenize

    toks = [t for w in re.findall(r"[A-Za-z0-9'’-]+", text) for t in (tokenize(w) or [w])]
    return any(toks[i : i + len(f)] == f for f in forms for i in range(len(toks) - len(f) + 1))


def object_prompt(prompt: str, name: str, others: tuple[str, ...] = ()) -> str | None:
    """The clause of ``prompt`` that names object ``name`` (None when none does).

    The prompt is cut into clauses at ``, ; . ! ?`` and the words ``and``, ``while``,
    ``whereas``, ``but``, ``then``: "the rubber ball bounces high and the jelly cube
    wobbles" gives "the rubber ball bounces high" for ``ball`` and "the jelly cube
    wobbles" for ``cube``. A clause names the object by its name (``_``/``-`` as
    blanks, plural-insensitive) or, when no clause uses the name, by a synonym the kb
    has for it ("duck" -> "rubber duck"). A clause that names only this object of
    ``others`` wins over one that names several; the first such clause is taken.
    ``objects[i].prompt`` replaces all of this when the words do not split so.
    """
    from motionphysics.init.estimate import _name_forms, _synonyms

    clauses = [c.strip() for c in _CLAUSE_SPLIT.split(prompt) if c and c.strip()]
    other_forms = [_name_forms(o) for o in others if o != name]
    for forms in (_name_forms(name), _name_forms("", _synonyms(name))):
        if not forms:
            continue
        hits = [c for c in clauses if _names_in(c, forms)]
        alone = [c for c in hits if not any(_names_in(c, f) for f in other_forms)]
        if alone or hits:
            return (alone or hits)[0]
    return None


def object_prompts(cfg, names: list[str], required: set[str] | None = None) -> dict[str, str]:
    """Each object's phrase for a prior that observes each object: ``objects[i].prompt``,
    else :func:`object_prompt` of the run's prompt; one error line for an object of
    ``required`` (default: all) that has neither, the others are left out."""
    given = {o.name: o.prompt for o in (cfg.objects or []) if getattr(o, "prompt", None)}
    required = set(names) if required is None else set(required)
    out = {}
    for i, n in enumerate(names):
        phrase = given.get(n) or object_prompt(cfg.prompt, n, tuple(names))
        if phrase is None and n not in required:
            continue
        if phrase is None:
            raise UserInputError(
                f"objects[{i}] ({n}): the prompt has no clause that names {n!r}, so the "
                "motion prior cannot tell what this object should do; name it in the prompt "
                f"or give objects[{i}].prompt"
            )
        out[n] = phrase
    return out


# --- the states prior, object by object -------------------------------------------------
class PerObjectLoss(Loss):
    """Sum over objects of each object's loss on that object's particles.

    ``parts``: ``(object name, particle indices [P_k] long, loss)`` per object; each loss
    receives a :class:`Prediction` holding only its object's particles (``xs [S,P_k,3]``,
    ``Fs [S,P_k,3,3]``). Components are each object's, prefixed ``OBJECT.``; the
    checkpointed state is each object's loss state."""

    name: ClassVar[str] = "per_object"

    def __init__(self, parts: list[tuple[str, Tensor, Loss]]):
        if not parts:
            raise ValueError("PerObjectLoss needs at least one object")
        if any(lo.needs_render for _, _, lo in parts):
            raise ValueError("PerObjectLoss: per-object losses observe states, not frames")
        self.parts = parts
        self.needs_states = True
        self._last: dict[str, float] = {}

    @property
    def label(self) -> str:
        return getattr(self.parts[0][2], "label", self.parts[0][2].name)

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        if pred.xs is None or pred.Fs is None:
            raise ValueError("PerObjectLoss reads the simulated states (Prediction.xs, Fs)")
        total = None
        last: dict[str, float] = {}
        for obj, idx, loss in self.parts:
            sub = Prediction(
                frame_indices=pred.frame_indices,
                xs=pred.xs.index_select(1, idx.to(pred.xs.device)),
                Fs=pred.Fs.index_select(1, idx.to(pred.Fs.device)),
            )
            value = loss(sub, ctx)
            last[obj] = float(value.detach())
            for k, v in loss.components().items():
                last[f"{obj}.{k}"] = v
            total = value if total is None else total + value
        self._last = last
        return total

    def components(self) -> dict[str, float]:
        return dict(self._last)

    def state_dict(self) -> dict:
        return {obj: lo.state_dict() for obj, _, lo in self.parts}

    def load_state_dict(self, state: dict) -> None:
        for obj, _, lo in self.parts:
            if obj in state:
                lo.load_state_dict(state[obj])


def object_indices(parts) -> list[Tensor]:
    """Particle indices [P_k] (long) of each object, in object order."""
    oid = np.asarray(parts.sim_scene.object_id).astype(np.int64)
    return [
        torch.as_tensor(np.nonzero(oid == k)[0], dtype=torch.long)
        for k in range(len(parts.objects))
    ]


def object_prior(prior, phrase: str, scene) -> Any:
    """A view of ``prior`` for one object: the same networks (a shallow copy), its own
    prompt cache and its own scene context (that object's rest state)."""
    view = copy.copy(prior)
    view._text = None
    view.set_scene(scene)
    view.set_prompt(phrase)
    return view
