"""Parameter names of several objects in the run directory's records.

A run of several objects records each object's parameters under its name
(``params: {duck: {E: ...}, block: {...}}``); the plots, the report, the viewer and the
summary read them as flat ``OBJECT.PARAM`` leaves (``duck.E``). Here, in ``io``, so the
writers do not import the optimiser (``optimize`` imports ``io``, not the reverse).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["SEP", "flat_params", "leaf"]

SEP = "."
"""Between an object's name and a parameter's in a leaf name (``duck.E``)."""


def leaf(obj: str, name: str) -> str:
    return f"{obj}{SEP}{name}"


def flat_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """A record's ``params`` with objects' values as ``OBJECT.PARAM`` keys (one object's
    records are returned as they are)."""
    out: dict[str, Any] = {}
    for k, v in params.items():
        if isinstance(v, Mapping) and not {"mean", "min", "max"} >= set(v):
            for n, x in v.items():
                out[leaf(k, n)] = x
        else:
            out[k] = v
    return out
