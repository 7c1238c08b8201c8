"""One entry point for material initialisation: ``estimate(prompt, image, backend)``.

Backends: ``kb`` (offline default: the curated knowledge base and MiniLM),
``llm`` (OpenAI-compatible chat model with the paper's ranged prompt), ``median``
and ``naive`` (the paper's ablation baselines). Every backend returns a
:class:`MaterialEstimate` whose values are physical (SI), inside the class ranges,
with every clamp recorded. Which ranges bound them is the range table
(``EstimateOptions.ranges``: ``extended``, the default, or ``paper``, the paper's
appendix table for its ablation; None: the active table of
:func:`motionphysics.materials.catalog.use_ranges`). Inputs are checked here (prompt text, image) and bad
ones raise :class:`~motionphysics.errors.UserInputError` with one line.
"""

from __future__ import annotations

import io
import json
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from motionphysics.errors import UserInputError
from motionphysics.init.baselines import MedianKind, median_params
from motionphysics.init.llm import LLMOptions, ask_material
from motionphysics.materials.catalog import (
    MATERIALS,
    MODEL_LIMIT_WORDS,
    MODEL_LIMITS,
    Clamp,
    MaterialParams,
    active_ranges,
    check_ranges,
    normalise_class,
    spec,
)

__all__ = [
    "BACKENDS",
    "MAX_PROMPT_CHARS",
    "EstimateOptions",
    "MaterialEstimate",
    "estimate",
    "estimate_many",
    "estimate_objects",
    "object_phrase",
    "check_prompt",
    "not_understood",
    "load_image_png",
]

Backend = Literal["kb", "llm", "median", "naive"]
BACKENDS: tuple[str, ...] = ("kb", "llm", "median", "naive")
MAX_PROMPT_CHARS = 10_000
"""Longest accepted prompt (a sentence or a paragraph, not a document)."""
MAX_IMAGE_SIDE = 1024
"""Reference images are downscaled to at most this many pixels per side before sending."""


@dataclass(frozen=True)
class EstimateOptions:
    """Backend options (all optional)."""

    llm: LLMOptions = LLMOptions()
    """Server, model, key, timeout of the ``llm`` and ``naive`` backends."""
    median: MedianKind = "arithmetic"
    """Which median the ``median`` backend uses for log-scaled parameters."""
    cls: str | None = None
    """Force the class (``median`` backend; the ablation compares values, not classes)."""
    announce: bool = True
    """Say on stderr what is being loaded (the MiniLM model) on first use, and that an LLM
    request is being waited for (on a terminal)."""
    verbose: bool = False
    """Also write the LLM waiting line when stderr is not a terminal."""
    ranges: str | None = None
    """The range table estimates are clamped into and the LLM is asked with: ``extended``
    or ``paper`` (the paper's table exactly); None: the active one (``extended`` unless a
    run set its config's ``init.ranges``)."""


@dataclass(frozen=True)
class MaterialEstimate:
    """An initial material: class, density [kg/m^3], physical values (SI), provenance."""

    cls: str
    density: float
    values: dict[str, float]
    backend: str
    confidence: float | None = None
    """kb: softmax probability of the class; median: None; llm/naive: None (not reported)."""
    clamped: list[Clamp] = field(default_factory=list)
    raw_answer: str | None = None
    """llm/naive: the model's reply text (both replies, separated, when re-asked)."""
    matches: list[dict[str, Any]] = field(default_factory=list)
    """kb: the top knowledge-base entries with their scores (the explanation)."""
    prompt: str = ""
    source: str | None = None
    """kb: the source of the chosen entry's values."""
    matched: str | None = None
    """kb: the prompt words that matched the chosen entry (None: similarity only)."""
    warnings: list[str] = field(default_factory=list)
    """Lines the user must see (kb: "not sure: ...", non-English prompt)."""
    notes: list[str] = field(default_factory=list)
    """Hints about substitutions already listed in ``clamped`` (kb: the entry's real value
    lies outside the class range, and how to simulate it anyway); ``init`` prints them,
    a run lists the substitutions in its summary instead."""
    adjusted: list[dict[str, Any]] = field(default_factory=list)
    """kb: values the prompt's modifiers moved ("soft": E 1.5e7 -> 1.7e6), each
    ``{"field", "from", "to", "words"}`` (before any clamp)."""
    ranges: str = "extended"
    """The range table the values were clamped into (``extended`` or ``paper``)."""
    understood: list[str] | None = None
    """kb: the words of the prompt it knows (names, class words, cues, modifiers)."""
    error: str | None = None
    """kb (and median without a class): set when the kb understood too little of the
    prompt to name a class (``init.kb.UNDERSTOOD_RULE``); the values are then a guess
    by sentence similarity that ``run`` and ``init`` refuse (exit status 2) unless the
    class is given. One line, worded for a run (see :func:`not_understood`)."""

    @property
    def params(self) -> MaterialParams:
        return MaterialParams(self.cls, self.density, dict(self.values))

    def material_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"class": self.cls, "density": float(self.density)}
        for name in MATERIALS[self.cls].names:
            out[name] = float(self.values[name])
        return out

    def to_dict(self) -> dict[str, Any]:
        """``{"material": {"class", "density", <params>}, "backend", "confidence", ...}``."""
        return {
            "material": self.material_dict(),
            "backend": self.backend,
            "confidence": self.confidence,
            "clamped": [c.to_dict() for c in self.clamped],
            "raw_answer": self.raw_answer,
            "matches": self.matches,
            "source": self.source,
            "prompt": self.prompt,
            "matched": self.matched,
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "adjusted": [dict(a) for a in self.adjusted],
            "ranges": self.ranges,
            "understood": None if self.understood is None else list(self.understood),
            "error": self.error,
        }

    def to_json(self, indent: int | None = None) -> str:
        return json.dumps(self.to_dict(), indent=indent)


def check_prompt(prompt: Any, where: str = "prompt") -> str:
    """The prompt, stripped; empty / too long / not text raise UserInputError."""
    if not isinstance(prompt, str):
        raise UserInputError(f"{where}: expected text, got {type(prompt).__name__}")
    text = prompt.strip()
    if not text:
        raise UserInputError(f"{where}: empty; describe the object and its motion in a sentence")
    if len(text) > MAX_PROMPT_CHARS:
        raise UserInputError(
            f"{where}: too long ({len(text)} characters; at most {MAX_PROMPT_CHARS})"
        )
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise UserInputError(f"{where}: not valid UTF-8 text") from None
    if any(ord(ch) < 32 and ch not in "\t\n\r" for ch in text):
        raise UserInputError(f"{where}: contains control characters")
    return text


def load_image_png(image: Any, where: str = "--image") -> bytes:
    """A reference image as PNG bytes (RGB, at most 1024 px per side).

    ``image``: a path (any format Pillow reads), raw image bytes, or an array
    ``[H, W, 3]`` (uint8, or float in [0, 1]). Unreadable -> UserInputError.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        if isinstance(image, (str, Path)):
            path = Path(image)
            where = f"{where} {path}"
            if not path.is_file():
                raise UserInputError(f"{where}: file not found")
            img = Image.open(path)
            img.load()
        elif isinstance(image, (bytes, bytearray)):
            img = Image.open(io.BytesIO(bytes(image)))
            img.load()
        else:
            import numpy as np

            arr = np.asarray(image)
            if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.size == 0:
                raise UserInputError(f"{where}: expected an image array [H, W, 3], got {arr.shape}")
            if arr.dtype != np.uint8:
                arr = (np.clip(arr.astype(np.float64), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
            img = Image.fromarray(arr)
    except UserInputError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise UserInputError(f"{where}: not a readable image ({type(err).__name__})") from None
    img = img.convert("RGB")
    if max(img.size) > MAX_IMAGE_SIDE:
        img.thumbnail((MAX_IMAGE_SIDE, MAX_IMAGE_SIDE))
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def _check_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise UserInputError(f"--backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    return backend


def not_understood(prompt: str, understood: list[str] | None, command: str = "run") -> str:
    """The one line of a prompt the kb understood too little of to name a class: what it
    understood and how to go on (``command``: ``run`` or ``init``, whose flags differ)."""
    from motionphysics.init.kb import mostly_not_english

    shown = prompt if len(prompt) <= 80 else prompt[:77] + "..."
    words = ", ".join(f"'{w}'" for w in understood or [])
    got = "no word of it names a material, an object, a class or a motion the kb knows"
    if words:
        got += f" (it understood only {words})"
    if mostly_not_english(prompt):
        got += " (the kb reads English only)"
    how = (
        "give material.class in the config, use --init llm, or write the prompt in English"
        if command == "run"
        else "use --backend llm, write the prompt in English, or give material.class in a "
        "run config"
    )
    return f"prompt: the kb backend cannot name a material class for {shown!r}: {got}; {how}"


def _from_kb(match, prompt: str, table: str) -> MaterialEstimate:
    from motionphysics.init.kb import apply_modifiers

    e = match.entry
    # The entry's real values (``real`` holds those outside even the extended range),
    # moved by the prompt's modifiers ("soft", "runny"), then clamped into the range
    # table: every value that is not the material's own is reported as a substitution.
    real = {**e.values, **{k: v for k, v in e.real.items() if k != "density"}}
    real, adjusted = apply_modifiers(match.cls, real, getattr(match, "modifiers", []))
    rho_real = float(e.real.get("density", e.density))
    clamped = []
    values: dict[str, float] = {}
    for k, x in (("density", rho_real), *real.items()):
        ps = spec(match.cls, k, table)
        used = ps.clip(float(x))
        if used != x:
            kind = "range floor" if x < used else "clamped"
            clamped.append(Clamp(k, float(x), float(used), kind, "kb"))
        values[k] = used
    density = values.pop("density")
    error = (
        None
        if getattr(match, "names_class", True)
        else not_understood(prompt, getattr(match, "understood", None))
    )
    # A prompt the kb cannot name a class for carries its error line instead of the
    # "not sure: closest ..." warnings of a guess nobody uses.
    warnings = [] if error else list(getattr(match, "warnings", []))
    if (
        not error
        and match.cls in MODEL_LIMITS
        and re.search(MODEL_LIMIT_WORDS[match.cls], prompt or "", re.I)
    ):
        warnings.append(f"kb: {match.cls}: {MODEL_LIMITS[match.cls]}")
    notes = []
    for c in clamped:
        if max(c.original, c.clamped) > 3.0 * min(c.original, c.clamped) > 0:
            side = "below the floor" if c.kind == "range floor" else "outside the range"
            notes.append(
                f"kb: the real {c.field} of {e.name} ({c.original:.3g}) is {side} of the "
                f"{match.cls} class ({c.clamped:.3g} is used); write material.{c.field}: "
                f"{c.original:.3g} in the config to simulate the real value"
            )
    return MaterialEstimate(
        cls=match.cls,
        density=density,
        values=values,
        backend="kb",
        confidence=round(match.confidence, 4),
        clamped=clamped,
        raw_answer=None,
        matches=match.matches,
        prompt=prompt,
        source=f"{e.name}: {e.source}",
        matched=getattr(match, "matched", None),
        warnings=warnings,
        notes=notes,
        adjusted=adjusted,
        ranges=table,
        understood=getattr(match, "understood", None),
        error=error,
    )


def estimate(
    prompt: str,
    image: Any = None,
    backend: Backend = "kb",
    options: EstimateOptions | None = None,
) -> MaterialEstimate:
    """Estimate the material of ``prompt`` (and an optional reference render ``image``)."""
    return estimate_many([prompt], image, backend, options)[0]


def estimate_many(
    prompts: list[str],
    image: Any = None,
    backend: Backend = "kb",
    options: EstimateOptions | None = None,
) -> list[MaterialEstimate]:
    """Estimate several prompts in order (the kb model and embeddings load once)."""
    opts = options or EstimateOptions()
    backend = _check_backend(backend)
    table = check_ranges(opts.ranges if opts.ranges is not None else active_ranges(), "--ranges")
    texts = [check_prompt(p) for p in prompts]
    png = load_image_png(image) if image is not None else None
    if backend == "kb":
        from motionphysics.init.kb import get_matcher

        matcher = get_matcher(announce=opts.announce)
        return [
            _from_kb(m, p, table) for m, p in zip(matcher.match_many(texts), texts, strict=True)
        ]
    if backend == "median":
        errors: list[str | None] = [None] * len(texts)
        understood: list[list[str] | None] = [None] * len(texts)
        if opts.cls is not None:
            classes = [normalise_class(opts.cls, field="--class")] * len(texts)
        else:
            from motionphysics.init.kb import get_matcher

            matches = get_matcher(announce=opts.announce).match_many(texts)
            classes = [m.cls for m in matches]
            understood = [m.understood for m in matches]
            errors = [
                None if m.names_class else not_understood(t, m.understood)
                for m, t in zip(matches, texts, strict=True)
            ]
        out = []
        for cls, text, err, known in zip(classes, texts, errors, understood, strict=True):
            p = median_params(cls, opts.median, table)
            out.append(
                MaterialEstimate(
                    cls,
                    p.density,
                    dict(p.values),
                    "median",
                    None,
                    [],
                    None,
                    [],
                    text,
                    f"{opts.median} median of the {table} ranges",
                    ranges=table,
                    understood=known,
                    error=err,
                )
            )
        return out
    out = []
    for text in texts:
        ans = ask_material(
            text, png, opts.llm, ranged=(backend == "llm"), announce=opts.announce, table=table
        )
        raw = (
            ans.raw_answers[0]
            if len(ans.raw_answers) == 1
            else ("\n\n--- re-asked ---\n\n".join(ans.raw_answers))
        )
        out.append(
            MaterialEstimate(
                ans.params.cls,
                ans.params.density,
                dict(ans.params.values),
                backend,
                None,
                list(ans.clamped),
                raw,
                [],
                text,
                "LLM answer" + (" with ranges" if backend == "llm" else " without ranges (naive)"),
                ranges=table,
            )
        )
    return out


# --- several objects of one prompt -------------------------------------------------------

# Words that end an object's phrase when walking back from its name ("a steel axe
# FALLS ONTO a rubber duck"): conjunctions, prepositions, common motion verbs, clause
# punctuation. Determiners are kept and stop the walk ("a", "the").
_PHRASE_STOP = frozenset(
    "and or but while as then onto on into in at to from with without against over under "
    "beside behind through across by near toward towards off falls fall falling drops drop "
    "dropped dropping hits hit hitting lands land landing slides slide rolls roll bounces "
    "bounce is are was were sits sit rests rest lies lie crashes crash strikes strike "
    "collides collide meets meet pushes push thrown throws thrown smashes smash".split()
)
_DETERMINERS = frozenset("a an the one two some this that his her its their my our".split())
_PHRASE_BACK = 4
"""Most words before an object's name that describe it ("a big shiny steel axe")."""


def _words(text: str) -> list[tuple[str, int, int]]:
    import re

    return [
        (m.group(0), m.start(), m.end()) for m in re.finditer(r"[A-Za-z0-9'’-]+|[,;.:!?]", text)
    ]


def _name_forms(name: str, synonyms: tuple[str, ...] = ()) -> list[list[str]]:
    """Token sequences that name an object: its name (``_``/``-`` as blanks) and
    synonyms, compared through the kb's plural-insensitive tokenizer."""
    from motionphysics.init.kb import tokenize

    forms = [tokenize(n.replace("_", " ").replace("-", " ")) for n in (name, *synonyms)]
    return [f for f in forms if f]


def _synonyms(name: str) -> tuple[str, ...]:
    """Other words the kb has for object ``name``: the aliases of the entry called so, and
    of entries whose name ends with it ("duck" -> "rubber duck", "rubber ducky"); the
    aliases of an entry that merely lists the name among many (a generic "animal
    figure" lists "duck" and "cat") are not synonyms."""
    from motionphysics.init.kb import load_kb, tokenize

    want = tokenize(name.replace("_", " "))
    out: list[str] = []
    for e in load_kb().entries:
        own = tokenize(e.name)
        if own == want or (len(own) > len(want) and own[-len(want) :] == want):
            out.extend(t for t in e.texts if tokenize(t) != want)
    return tuple(dict.fromkeys(out))


def object_phrase(prompt: str, name: str, synonyms: tuple[str, ...] = ()) -> str | None:
    """The words of ``prompt`` that describe object ``name`` ("a steel axe falls onto a
    rubber duck", "axe" -> "a steel axe"), or None when neither the name nor a synonym
    occurs. The phrase runs from a determiner or stop word before the name (at most
    ``_PHRASE_BACK`` words back) to the name, plus a following ``made of X`` / ``of X``.
    """
    from motionphysics.init.kb import tokenize

    words = _words(prompt)
    toks = [tokenize(w)[0] if tokenize(w) else w for w, _, _ in words]
    # the name itself first; a synonym only when the prompt does not use the name
    own = _name_forms(name)
    others = sorted(_name_forms("", synonyms), key=len, reverse=True)
    for form in own + others:
        n = len(form)
        for i in range(len(toks) - n + 1):
            if toks[i : i + n] != form:
                continue
            start = i
            for j in range(i - 1, max(-1, i - 1 - _PHRASE_BACK), -1):
                w = words[j][0].lower()
                if w in _PHRASE_STOP or not w[0].isalnum():
                    break
                start = j
                if w in _DETERMINERS:
                    break
            end = i + n
            rest = [w.lower() for w, _, _ in words[end : end + 2]]
            if rest[:2] == ["made", "of"] or rest[:1] == ["of"]:
                end += 2 if rest[0] == "made" else 1
                while end < len(words) and words[end][0][0].isalnum():
                    w = words[end][0].lower()
                    if w in _PHRASE_STOP:
                        break
                    end += 1
            return prompt[words[start][1] : words[end - 1][2]]
    return None


def estimate_objects(
    prompt: str,
    names: list[str],
    image: Any = None,
    backend: Backend = "kb",
    options: EstimateOptions | None = None,
) -> list[MaterialEstimate]:
    """One estimate per object of one ``prompt`` (in ``names`` order).

    kb / median: each object's phrase (:func:`object_phrase`, by its name and the kb's
    synonyms) is estimated on its own; an object the prompt does not name falls back to
    the whole sentence with a warning naming it. llm / naive: one request listing the
    object names, one JSON answer per name (:func:`init.llm.ask_objects`), each
    range-checked and clamped as a single answer.
    """
    opts = options or EstimateOptions()
    backend = _check_backend(backend)
    table = check_ranges(opts.ranges if opts.ranges is not None else active_ranges(), "--ranges")
    opts = replace(opts, ranges=table)
    text = check_prompt(prompt)
    if not names:
        return []
    if backend in ("kb", "median"):
        phrases, notes = [], []
        for name in names:
            phrase = object_phrase(text, name, _synonyms(name))
            if phrase is None:
                notes.append(
                    f"{backend}: object {name!r} is not named in the prompt; its material is "
                    "estimated from the whole sentence (name the object in the prompt, or give "
                    f"objects[{name}].material)"
                )
                phrases.append(text)
            else:
                notes.append(None)
                phrases.append(phrase)
        ests = estimate_many(phrases, image if backend != "kb" else None, backend, opts)
        out = []
        for est, note in zip(ests, notes, strict=True):
            warnings = ([note] if note else []) + list(est.warnings)
            out.append(replace(est, warnings=warnings))
        if opts.announce:
            import sys

            for w in (n for n in notes if n):
                print(f"motionphysics: warning: {w}", file=sys.stderr)
        return out
    from motionphysics.init.llm import ask_objects

    png = load_image_png(image) if image is not None else None
    answers = ask_objects(
        text,
        list(names),
        png,
        opts.llm,
        ranged=(backend == "llm"),
        announce=opts.announce,
        table=table,
    )
    out = []
    for name in names:
        ans = answers[name]
        raw = "\n\n--- re-asked ---\n\n".join(ans.raw_answers)
        out.append(
            MaterialEstimate(
                ans.params.cls,
                ans.params.density,
                dict(ans.params.values),
                backend,
                None,
                list(ans.clamped),
                raw,
                [],
                text,
                f"LLM answer for object {name!r}"
                + (" with ranges" if backend == "llm" else " without ranges (naive)"),
                ranges=table,
            )
        )
    return out
