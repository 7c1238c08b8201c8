"""Combine what a person wrote with an estimate: which value each field takes and why.

Precedence per field: the config's ``material:`` block > a ``--params`` file > the
estimate of an init backend (kb, llm, median) > the centre of the class's handbook
range (only when the class was changed so nothing else names the field).

What each source gets (issue "say what you do"):

* values a person wrote (config, params file) are used **as written** when they are
  physical, also outside the handbook range: the ranges bound estimates (as the paper
  uses them), they are not laws. Outside the range: one warning line each.
  Physically impossible values (:data:`~motionphysics.materials.catalog.PHYSICAL_LIMITS`)
  are errors.
* estimates are clamped into the ranges of the run's range table (``init.ranges``:
  ``extended``, the default, or ``paper``; ``ranges=`` here, else the active table of
  :func:`~motionphysics.materials.catalog.use_ranges`); every substitution is a
  :class:`~motionphysics.materials.catalog.Clamp` tagged ``clamped`` (or ``range floor``
  when the estimator itself set a below-range real value to the floor) with its source.

This module must not map values to the simulator (that is :mod:`.simmap`) nor print.
"""

from __future__ import annotations

import math
from typing import Any

from motionphysics.errors import UserInputError
from motionphysics.materials.catalog import (
    Clamp,
    MaterialParams,
    active_ranges,
    check_physical,
    check_ranges,
    materials,
    normalise_class,
    range_notes,
    spec,
    validate,
)

__all__ = ["resolve_material", "range_centre"]


def range_centre(cls: str, name: str, table: str | None = None) -> float:
    """Centre of a parameter's handbook range (geometric for log-scaled ones; the default
    when the parameter has one) in range table ``table`` (None: the active one)."""
    ps = spec(cls, name, table)
    if ps.default is not None:
        return float(ps.default)
    if ps.scale == "log" and ps.low > 0:
        return math.sqrt(ps.low * ps.high)
    return 0.5 * (ps.low + ps.high)


def _not_understood(estimate: dict[str, Any]) -> str | None:
    """The estimate's "cannot name a class" line (``error`` of the backend's record)."""
    return estimate.get("error") or (estimate.get("estimate") or {}).get("error")


def resolve_material(
    cls_given: str | None,
    given: dict[str, float],
    estimate: dict[str, Any] | None = None,
    base: dict[str, Any] | None = None,
    *,
    config_origin: str = "material",
    ranges: str | None = None,
) -> dict[str, Any]:
    """Resolve the material of a run.

    ``cls_given``/``given``: the config's ``material.class`` and physical fields
    (``MaterialConfig.overrides()``). ``estimate``: ``{class, density, params, backend,
    clamps}`` of an init backend (clamps: dicts with ``kind`` when the backend tagged
    them). ``base``: a params file ``{class, density, params, origin}``. ``ranges``: the
    range table estimates are clamped into and written values are checked against
    (``extended``, ``paper``; None: the active one, ``catalog.active_ranges()``).

    An estimate whose backend could not name a class (its record's ``error``: the kb
    understood too little of the prompt) is refused with that line as a
    :class:`UserInputError` unless the config or the params file gives the class; then
    none of its values is used (the missing fields take the range centre, with one
    warning line).

    Returns ``{"material": MaterialParams, "clamps": [dict], "warnings": [str],
    "range_notes": [dict], "sources": {name: str}, "overrides": given,
    "class_override": bool}``. ``clamps`` lists every substitution (estimate clamps
    included) with ``kind`` and ``source``; ``warnings`` one line per value used as
    written outside its range.
    """
    guess_dropped = None
    if estimate is not None and _not_understood(estimate) and (cls_given or base is not None):
        # The class is given: the estimate (a guess by sentence similarity) gives nothing.
        guess_dropped, estimate = estimate, None
    base_name = (base or {}).get("origin", "params file")
    est_name = (estimate or {}).get("backend", "estimate")
    start = base if base is not None else estimate
    start_name = base_name if base is not None else est_name
    if cls_given is not None:
        cls = normalise_class(cls_given, field=f"{config_origin}.class")
    elif base is None and estimate is not None and _not_understood(estimate):
        # The kb understood too little of the prompt to name a class (issue 27): its
        # guess by sentence similarity is not passed off as an answer.
        raise UserInputError(_not_understood(estimate))
    elif start is not None and start.get("class") is not None:
        cls = normalise_class(start["class"], field=f"{start_name}.class")
    else:
        raise UserInputError(
            f"{config_origin}.class: missing (give it in the config or pass --params FILE)"
        )
    table = check_ranges(ranges if ranges is not None else active_ranges())
    names = materials(table)[cls].names

    def same(src):
        return (
            src is not None
            and src.get("class") is not None
            and normalise_class(src["class"], field="class") == cls
        )

    extra = sorted(k for k in given if k != "density" and k not in names)
    if extra:
        raise UserInputError(
            f"{config_origin}: parameter(s) {', '.join(extra)} do not belong to class {cls} "
            f"(expected {', '.join(names)})"
        )
    if base is not None and same(base):
        stray = sorted(k for k in (base.get("params") or {}) if k not in names)
        if stray:
            raise UserInputError(
                f"{base_name}: parameter(s) {', '.join(stray)} do not belong to class {cls} "
                f"(expected {', '.join(names)})"
            )
    written: dict[str, float] = {}  # by a person: used as written
    estimated: dict[str, float] = {}  # by a backend: clamped
    sources: dict[str, str] = {}
    for name in ("density", *names):
        if name in given:
            written[name] = check_physical(name, given[name], f"{config_origin}.{name}")
            sources[name] = "config"
            continue
        picked = False
        for src, label, kind in ((base, "params file", "written"), (estimate, est_name, "est")):
            if src is None or not (same(src) or name == "density"):
                continue
            v = src.get("density") if name == "density" else (src.get("params") or {}).get(name)
            if v is None:
                continue
            where = base_name if kind == "written" else est_name
            x = check_physical(name, v, f"{where}.{name}")
            (written if kind == "written" else estimated)[name] = x
            sources[name] = label
            picked = True
            break
        if not picked:
            written_default = range_centre(cls, name, table)
            estimated[name] = written_default
            sources[name] = f"range centre of {cls}"
    # Estimates: clamp (tagged with the backend); written values: kept.
    est_vals = {k: v for k, v in estimated.items() if k != "density"}
    # Validate the whole set once (all fields present), keeping written ones as given.
    merged = {**estimated, **written}
    density = merged.pop("density")
    params, _ = validate(
        cls, merged, density=density, on_out_of_range="keep", origin="material", table=table
    )
    clamps: list[Clamp] = []
    values = dict(params.values)
    rho = params.density
    for name, v in {
        **est_vals,
        **({"density": estimated["density"]} if "density" in estimated else {}),
    }.items():
        ps = spec(cls, name, table)
        if not ps.contains(v):
            y = ps.clip(v)
            clamps.append(Clamp(name, v, y, "clamped", sources[name]))
            if name == "density":
                rho = y
            else:
                values[name] = y
    params = MaterialParams(cls, rho, values)
    # The backend's own substitutions (it clamped before we saw the value; the kb's
    # "real value below the class floor") are kept with their tags.
    seen = {c.field for c in clamps}
    prior = []
    for c in (estimate or {}).get("clamps") or []:
        if c.get("field") in seen or sources.get(c.get("field")) != est_name:
            continue
        prior.append(
            Clamp(
                c["field"],
                float(c["original"]),
                float(c["clamped"]),
                c.get("kind", "clamped"),
                c.get("source", est_name),
            )
        )
    notes = range_notes(params, fields=set(written), table=table)
    dropped = []
    if guess_dropped is not None:
        centred = [n for n, src in sources.items() if src.startswith("range centre")]
        if centred:
            dropped.append(
                f"warning: {guess_dropped.get('backend', 'kb')} backend: no word of the prompt "
                f"names a material it knows; {', '.join(centred)} of {cls} from the centre "
                "of the class range (give them in the config)"
            )
    origin_of = {n: (config_origin if sources[n] == "config" else base_name) for n in written}
    return {
        "material": params,
        "clamps": [c.to_dict() for c in prior + clamps],
        "warnings": [r.text(origin_of[r.field].rsplit(".", 0)[0]) for r in notes] + dropped,
        "range_notes": [r.to_dict() for r in notes],
        "sources": sources,
        "overrides": dict(given),
        "class_override": cls_given is not None and (start is None or not same(start)),
        "ranges": table,
    }
