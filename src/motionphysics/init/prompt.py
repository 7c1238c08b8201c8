"""The LLM inquiry prompt: the paper's appendix template, built from the catalogue.

Structure (as in the paper): the inputs (the textual simulation prompt and, when
given, a reference image), the question (decide the material mainly from the text,
use the image as secondary reference only), the material types with their
required parameters and units, the allowed range of every parameter (``ranged``
prompt only), and the exact JSON answer format.

Deviation from the paper's template, on purpose: every value is asked in SI units
(``kappa`` in Pa rather than kPa, ``mu`` in Pa s rather than mPa s) so the answer
needs no unit conversion, and the non-Newtonian power-law index ``n`` is offered
as an optional field (default 1 = Bingham). The ranges are read from
:mod:`motionphysics.materials.catalog` — this module holds no numbers — in the run's
range table: ``extended`` (the default; the inquiry then also asks for the named
material's real values and says that modifiers such as "soft" or "runny" move values
within the type the noun names) or ``paper`` (the paper's table and template exactly).

The ``naive`` variant is PhysFlow's unconstrained inquiry: same question and answer
format, no ranges.
"""

from __future__ import annotations

import base64
from typing import Any

from motionphysics.materials.catalog import (
    DENSITY,
    MATERIALS,
    active_ranges,
    check_ranges,
    materials,
)

__all__ = ["build_prompt", "build_messages", "image_part", "repair_message", "SYSTEM_MESSAGE"]

SYSTEM_MESSAGE = (
    "You are an expert in continuum mechanics and material science. You answer with a "
    "single JSON object and nothing else."
)

_UNIT_TEXT = {"Pa": "Pa", "1": "unitless", "deg": "degrees", "Pa s": "Pa·s"}


def _param_line(cls: str) -> str:
    mc = MATERIALS[cls]
    parts = []
    for ps in mc.params:
        opt = f", optional, default {ps.default:g}" if ps.default is not None else ""
        parts.append(f"{ps.name} ({ps.description}, {_UNIT_TEXT.get(ps.unit, ps.unit)}{opt})")
    return f'- {mc.label} ("{cls}"): ' + ", ".join(parts)


MODIFIER_GUIDANCE = (
    "Give the real handbook values of the material the prompt names. Words such as soft, "
    "stiff, squishy, runny or thick move the values within the material type the noun names "
    "and do not change the type (a soft rubber ball is a soft elastic material, thick honey "
    "a more viscous Newtonian fluid)."
)
"""Said in the ranged ``extended`` inquiry only (the ``paper`` one is the paper's template,
the naive one PhysFlow's)."""


def _range_lines(cls: str, table: str) -> list[str]:
    mc = materials(table)[cls]
    lines = [f"- {mc.label}:"]
    for ps in mc.params:
        lines.append(f"  - {ps.name}: {ps.range_text()}")
    return lines


def _answer_format() -> str:
    keys = ["E", "nu", "tau_Y", "eta", "theta_fric", "mu", "kappa", "n"]
    body = ",\n".join(
        ['  "material_type": "..."', '  "density": ...'] + [f'  "{k}": ...' for k in keys]
    )
    return "{\n" + body + "\n}"


def build_prompt(
    text: str, ranged: bool = True, has_image: bool = False, table: str | None = None
) -> str:
    """The inquiry text for one simulation prompt (``ranged=False``: PhysFlow's naive one)
    with the ranges of range table ``table`` (``extended``, ``paper``; None: the active one)."""
    table = check_ranges(table if table is not None else active_ranges(), "--ranges")
    lines = ["Inputs:", f"- Textual simulation prompt: {text!r}"]
    if has_image:
        lines.append("- Reference image: attached (a render of the scene).")
    lines += [
        "",
        "Q: What is this object? Based primarily on the textual simulation prompt, determine "
        "the most appropriate material type. Then estimate its density (kg/m^3) and relevant "
        "physical parameters."
        + (" Use the image as secondary visual reference only." if has_image else ""),
    ]
    if ranged and table == "extended":
        lines.append(MODIFIER_GUIDANCE)
    lines += [
        "",
        "Material types (use the id in quotes as material_type) and required parameters "
        "(SI units):",
    ]
    lines += [_param_line(cls) for cls in MATERIALS]
    if ranged:
        lines += [
            "",
            "Warning: all inferred physical parameters must strictly fall within the "
            "following valid ranges (SI units):",
        ]
        for cls in MATERIALS:
            lines += _range_lines(cls, table)
        lines.append(f"- Density (all types): {DENSITY.range_text()}")
    lines += [
        "",
        "Respond in this exact format (a single JSON object, numbers as plain JSON numbers "
        "in SI units, e.g. 2.1e11):",
        _answer_format(),
        "Only include fields relevant to the inferred material type.",
    ]
    return "\n".join(lines)


def image_part(png: bytes) -> dict[str, Any]:
    """An OpenAI chat content part carrying ``png`` as a base64 data URL."""
    b64 = base64.b64encode(png).decode("ascii")
    return {"type": "image_url", "image_url": {"url": f"data:image/png;base64,{b64}"}}


def build_messages(
    text: str, image_png: bytes | None = None, ranged: bool = True, table: str | None = None
) -> list[dict]:
    """Chat Completions messages: system, then the inquiry (text part + optional image part)."""
    inquiry = build_prompt(text, ranged=ranged, has_image=image_png is not None, table=table)
    if image_png is None:
        content: Any = inquiry
    else:
        content = [{"type": "text", "text": inquiry}, image_part(image_png)]
    return [{"role": "system", "content": SYSTEM_MESSAGE}, {"role": "user", "content": content}]


def repair_message(error: str) -> dict:
    """The follow-up user message of the single re-ask after an invalid answer."""
    return {
        "role": "user",
        "content": (
            f"Your answer could not be used: {error}. Answer again with a single JSON object "
            "in exactly the requested format, with material_type one of "
            + ", ".join(f'"{c}"' for c in MATERIALS)
            + " and every required parameter of that type as a number."
        ),
    }


def build_objects_prompt(
    text: str,
    names: list[str],
    ranged: bool = True,
    has_image: bool = False,
    table: str | None = None,
) -> str:
    """The inquiry for a scene of several objects: the one-object inquiry, asking for one
    JSON object per object name (keys: the names, exactly as given)."""
    base = build_prompt(text, ranged=ranged, has_image=has_image, table=table)
    listed = ", ".join(f'"{n}"' for n in names)
    example = (
        "{\n"
        + ",\n".join(f'  "{n}": {{"material_type": "...", "density": ...}}' for n in names)
        + "\n}"
    )
    return (
        base
        + "\n\nThe scene holds several objects, each of its own material: "
        + listed
        + ". Determine the material of each object from the part of the prompt that "
        "describes it. Respond with a single JSON object whose keys are exactly these "
        "object names, each mapping to one answer in the format above, e.g.\n" + example
    )


def build_objects_messages(
    text: str,
    names: list[str],
    image_png: bytes | None = None,
    ranged: bool = True,
    table: str | None = None,
) -> list[dict]:
    """Chat messages of :func:`build_objects_prompt` (system, inquiry + optional image)."""
    inquiry = build_objects_prompt(
        text, names, ranged=ranged, has_image=image_png is not None, table=table
    )
    content: Any = (
        inquiry if image_png is None else [{"type": "text", "text": inquiry}, image_part(image_png)]
    )
    return [{"role": "system", "content": SYSTEM_MESSAGE}, {"role": "user", "content": content}]
