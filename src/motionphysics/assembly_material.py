"""The material phase of the assembly: the init backend's estimate and the resolved
material with its provenance (config ``material:`` block > ``--params`` file > estimate >
the class's range centre).

:func:`estimate_material` runs an init backend on the prompt and the reference render;
:func:`resolve_material` combines it with the config; :func:`warn` is the one way a
material or simulation warning reaches the person (stderr and the observer). Re-exported
by :mod:`motionphysics.assembly`; builds no simulation and writes no file.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from motionphysics.config import RunConfig
from motionphysics.events import Observer

__all__ = ["estimate_material", "resolve_material", "warn", "material_complete"]


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


def estimate_material(prompt: str, image, backend: str, announce: bool = False) -> dict[str, Any]:
    """Run an init backend (CONTRACTS.md, "init").

    ``image`` is the reference render, uint8 [H, W, 3]. Returns ``{class, density,
    params, backend, raw, clamps, estimate}`` (``estimate``: the backend's full record).
    """
    from motionphysics.init import EstimateOptions, estimate

    # ``announce``: the kb backend reports its model load on stderr (only on a verbose run).
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

    Delegates to :func:`motionphysics.materials.resolve.resolve_material`: precedence per
    field config ``material:`` > ``base`` (``--params`` file) > ``estimate`` > centre of
    the class's handbook range; values a person wrote are used as written (one warning
    line when outside the handbook range), estimates are clamped and tagged. Returns
    ``{"material", "clamps", "warnings", "range_notes", "sources", "overrides",
    "class_override"}``.
    """
    from motionphysics.materials.resolve import resolve_material as _resolve

    return _resolve(
        cfg.material.class_,
        cfg.material.overrides(),
        estimate=estimate,
        base=base,
        config_origin="material",
    )


def warn(text: str, observer: Observer | None = None) -> None:
    """A warning about the material or the simulation: always on stderr (``--quiet``
    never hides it), and to the observer for displays that keep a log."""
    print(text if text.startswith("warning") else f"warning: {text}", file=sys.stderr)
    if observer is not None:
        observer.message("warning", text)


def _provenance(est: dict[str, Any] | None, res: dict[str, Any], params_file=None) -> dict:
    """Where a material's fields came from (``params.json`` provenance): the backend,
    its raw answer and estimate, the substitutions and the per-field sources."""
    backend = "params file" if params_file is not None else est["backend"] if est else "config"
    return {
        "backend": backend,
        "params_file": params_file.get("origin") if params_file is not None else None,
        "raw_answer": est.get("raw") if est else None,
        "estimate": est.get("estimate") if est else None,
        "clamps": res["clamps"],
        "estimate_clamps": est.get("clamps", []) if est else [],
        "overrides": res["overrides"],
        "class_override": res["class_override"],
        "sources": res["sources"],
    }


def material_complete(cfg: RunConfig) -> bool:
    """True when the config's ``material:`` block names a class and all of its parameters."""
    from motionphysics.materials.catalog import MATERIALS, normalise_class

    m = cfg.material
    if m.class_ is None or m.density is None:
        return False
    given = m.overrides()
    mc = MATERIALS[normalise_class(m.class_, field="material.class")]
    return all(p.name in given or getattr(p, "default", None) is not None for p in mc.params)
