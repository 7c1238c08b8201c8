"""Captions of the motion prior's training clips, written from the MEASURED motion.

:func:`motion_group` puts a clip into one of the eight motion groups from the numbers
of :func:`~motionphysics.priors.motion_data.motion_measures` (rebound ratio, height and
spread ratios, shape change, wobble count, late speed), or into ``None`` when the clip
satisfies no group's conditions with a margin (those clips are captioned only with
their object and material nouns and a neutral "falls" phrase, never with a motion
claim). Each group's rule is a conjunction of inequalities on the measures, and the
groups exclude one another, so a caption can never say "bounces high" about a clip
that stayed down, "keeps its shape" about one that flattened, and so on.

Phrasings come in two disjoint sets: ``TRAIN`` with ``PARAPHRASES`` (used to caption
training clips, :func:`training_phrasings`) and ``HELD_OUT`` (never used in training: the
discrimination measurement uses them).
Material nouns follow the clip's class (a rubber ball, a lump of clay, honey...),
object nouns its shape.

This module must not import torch or the simulator.
"""

from __future__ import annotations

import functools
from collections.abc import Collection, Mapping, Sequence

import numpy as np

__all__ = [
    "GROUPS",
    "GROUP_CLASS",
    "HELD_OUT",
    "TRAIN",
    "OPPOSITE",
    "PARAPHRASES",
    "prompt_clauses",
    "prompt_subject",
    "caption_clip",
    "contrast_prompt",
    "firmness",
    "group_prompt",
    "heap_side",
    "motion_group",
    "object_noun",
    "prompt_motion_group",
    "prompt_motion_reading",
    "training_phrasings",
]

GROUPS = (
    "bounces_high",
    "barely_bounces",
    "wobbles",
    "splashes",
    "oozes",
    "keeps_shape",
    "crumbles",
    "squashes_flat",
)
"""The motion groups, in a fixed order (their index is the class label in evaluations)."""

TRAIN: dict[str, tuple[str, ...]] = {
    "bounces_high": (
        "bounces high",
        "bounces back up",
        "rebounds strongly off the ground",
        "hits the floor and springs back up",
        "is springy and bounces",
        "bounces like a rubber ball",
    ),
    "barely_bounces": (
        "barely bounces",
        "bounces only a little",
        "hops slightly after landing",
        "gives a small bounce and settles",
        "lands with a weak rebound",
    ),
    "wobbles": (
        "wobbles",
        "wobbles like jelly",
        "jiggles after it lands",
        "squashes and wobbles back",
        "quivers and oscillates on the ground",
    ),
    "splashes": (
        "splashes and spreads",
        "splashes and spreads thin",
        "splashes across the floor",
        "runs out into a thin puddle",
        "flows out quickly like water",
    ),
    "oozes": (
        "oozes slowly",
        "oozes slowly like honey",
        "flows slowly and thickly",
        "slumps and creeps outward",
        "sags and spreads sluggishly",
    ),
    "keeps_shape": (
        "keeps its shape",
        "stays rigid when it lands",
        "lands without deforming",
        "hits the ground and stays intact",
        "does not deform at all",
    ),
    "crumbles": (
        "crumbles into a heap",
        "collapses into a pile",
        "falls apart into a mound of grains",
        "crumbles and settles in a heap",
        "breaks down into a loose pile",
    ),
    "squashes_flat": (
        "squashes and stays flat",
        "flattens and stays squashed",
        "is squashed permanently",
        "dents and keeps the dent",
        "squishes down and does not recover",
    ),
}

HELD_OUT: dict[str, tuple[str, ...]] = {
    "bounces_high": ("jumps right back up after hitting the floor", "is very bouncy"),
    "barely_bounces": ("bounces just a tiny bit", "rebounds feebly"),
    "wobbles": ("shakes and jiggles like gelatin", "trembles after the impact"),
    "splashes": ("splatters and spreads out widely", "spills out flat like a liquid"),
    "oozes": ("creeps out slowly like syrup", "flows very slowly like thick goo"),
    "keeps_shape": ("holds its form on impact", "stays perfectly solid"),
    "crumbles": ("disintegrates into a pile", "falls to pieces in a mound"),
    "squashes_flat": ("gets flattened and stays that way", "deforms into a flat shape"),
}

PARAPHRASES: dict[str, tuple[str, ...]] = {
    "bounces_high": (
        "bounces up high",
        "springs back into the air",
        "rebounds high off the floor",
        "bounds back up",
        "leaps up again after landing",
        "bounces back almost to where it started",
        "shoots back up off the ground",
    ),
    "barely_bounces": (
        "bounces a little and stops",
        "makes a small hop",
        "rebounds only slightly",
        "lands with a soft little bounce",
        "bounces weakly once",
        "comes up only a short way after landing",
    ),
    "wobbles": (
        "wobbles back and forth",
        "jiggles and wobbles",
        "sways and jiggles after landing",
        "quivers like jelly",
        "shudders and wobbles in place",
        "jiggles back into shape",
    ),
    "splashes": (
        "splashes everywhere",
        "splashes onto the floor",
        "spreads out into a wide puddle",
        "gushes outward across the floor",
        "flows out fast and thin",
        "sloshes outward into a puddle",
    ),
    "oozes": (
        "oozes out gradually",
        "seeps outward slowly",
        "slowly slumps into a thick puddle",
        "flows like honey",
        "oozes like molasses",
        "sluggishly sags and spreads",
    ),
    "keeps_shape": (
        "stays rigid",
        "does not change shape",
        "lands and stays whole",
        "stays hard and undeformed",
        "remains unchanged after landing",
        "lands like a rock",
    ),
    "crumbles": (
        "crumbles apart",
        "collapses into a heap of grains",
        "crumbles like dry sand",
        "slumps into a sandy mound",
        "breaks up into loose grains",
        "falls apart into a heap",
    ),
    "squashes_flat": (
        "squashes flat",
        "is crushed into a pancake",
        "squashes down and stays squashed",
        "flattens permanently",
        "splats and stays flat",
        "gets squished flat and never recovers",
    ),
}
"""More training captions of each group (paraphrase augmentation, motion prior features
version 3): everyday words for the same motions, so that the prior learns the motion from
more than the six phrasings of :data:`TRAIN`. Written without the distinctive words of
:data:`HELD_OUT` (no "feebly", "tiny bit", "gelatin", "trembles", "splatters", "spills",
"syrup", "goo", "holds its form", "perfectly solid", "disintegrates", "pieces",
"flattened", "deforms"), which stay unseen in training. Captions only: prompts are read
(:func:`prompt_motion_reading`) from :data:`TRAIN`, :data:`HELD_OUT` and
:data:`READING_EXTRA` as before."""


def training_phrasings(group: str) -> tuple[str, ...]:
    """Every phrasing a training clip of ``group`` may be captioned with."""
    return (*TRAIN[group], *PARAPHRASES[group])


GROUP_CLASS: dict[str, str] = {
    "bounces_high": "elastic",
    "barely_bounces": "elastic",
    "wobbles": "elastic",
    "splashes": "newtonian",
    "oozes": "newtonian",
    "keeps_shape": "metal",
    "crumbles": "sand",
    "squashes_flat": "plasticine",
}
"""The material class a motion suggests when the prompt names no material (the kb's
motion reading): a high or small bounce and a wobble are elastic, a splash and an ooze
are liquids, keeping its shape is rigid (metal), crumbling is granular, squashing flat
and staying so is plastic."""

NEUTRAL = ("falls onto the ground", "drops onto the floor", "is dropped")
"""Phrases for clips no group fits (no motion claim)."""

READING_EXTRA: dict[str, tuple[str, ...]] = {
    "bounces_high": (
        "bounces several times",
        "keeps bouncing",
        "leaps back up",
        "bounces off the floor",
        "springs off the ground",
        "bounces up and down",
    ),
    "barely_bounces": (
        "thuds down with a tiny rebound",
        "lands with a dull thud and a little hop",
        "bounces once, weakly",
    ),
    "wobbles": (
        "jiggles like a pudding",
        "vibrates after landing",
    ),
    "splashes": (
        "spills across the floor",
        "pours out and spreads",
        "splatters everywhere",
        "sloshes and spreads out",
        "bursts into a puddle",
    ),
    "oozes": (
        "drips slowly",
        "flows like thick syrup",
        "slowly sags into a puddle",
        "creeps along sluggishly",
    ),
    "keeps_shape": (
        "stays intact",
        "does not bend",
        "remains solid and undamaged",
        "does not break or bend",
    ),
    "crumbles": (
        "falls apart into grains",
        "breaks apart into powder",
        "collapses into a pile of sand",
        "slumps into a heap of grains",
    ),
    "squashes_flat": (
        "flattens into a pancake",
        "is crushed flat",
        "gets dented",
        "bends and stays bent",
        "splats flat and stays flat",
    ),
}
"""More phrasings of each group that only READ prompts (the contrast, the motion asked
for, the kb's motion reading): never a training caption, so the prior's held-out
discrimination is unaffected. Everyday words a user writes for each motion."""

READING_NEUTRAL = (
    *NEUTRAL,
    "hits the ground",
    "hits the floor",
    "lands on the ground",
    "falls over",
    "is thrown",
    "falls from a height",
    "tips over",
)
"""Clauses that tell an event, not a motion: a clause at least as close to one of these as
to every group's phrasings makes no motion claim ("A ball hits the ground and leaps back
up" is read from "leaps back up", not from "hits the ground")."""

FIRMNESS: dict[str, tuple[str, ...]] = {
    "stiff": ("stiff", "hard", "firm"),
    "soft": ("soft", "squishy", "floppy"),
}
"""Adjectives a caption may put before the noun of a solid from how far it deformed at its
worst (``max_deform``, the distance from the best rigid motion over the object size):
``stiff`` below :data:`STIFF_MAX_DEFORM`, ``soft`` above :data:`SOFT_MAX_DEFORM`, none in
between. A person calls a ball stiff or soft from how much it gives on impact, not from
how high it comes back (in our simulator a soft jelly rebounds as high as a hard ball:
the training data's high bouncers span E from 10 to 10^5 x rho g L), so without these
words "stiff, bounces high" and "soft, bounces high" name the same clips."""

STIFF_MAX_DEFORM = 0.02
"""Peak deformation below which a solid is called stiff (the ``keeps_shape`` bound)."""

SOFT_MAX_DEFORM = 0.03
"""Peak deformation above which a solid is called soft (the ``wobbles`` bound)."""

FLOW_GROUPS = frozenset({"splashes", "oozes", "crumbles"})


def firmness(measures: Mapping[str, float], group: str | None) -> str | None:
    """``"stiff"``, ``"soft"`` or None for a clip: None for a flow (it has no shape to
    keep) and between the two bounds."""
    if group in FLOW_GROUPS or measures.get("granular", 0.0):
        return None
    if group is None and (measures["spread"] > 1.5 or measures["deform"] > 0.15):
        return None
    d = measures["max_deform"]
    if d < STIFF_MAX_DEFORM:
        return "stiff"
    if d > SOFT_MAX_DEFORM:
        return "soft"
    return None


_MATERIAL = {
    "elastic": ("rubber", "elastic", "rubbery"),
    "plasticine": ("clay", "plasticine", "modelling clay"),
    "metal": ("metal", "steel", "metallic"),
    "foam": ("foam", "spongy", "sponge"),
    "sand": ("sand", "sandy", "granular"),
    "newtonian": ("liquid", "water", "fluid"),
    "non_newtonian": ("paste", "goo", "slime"),
}

_OBJECT = {
    "sphere": ("ball", "sphere"),
    "cube": ("cube", "block"),
    "column": ("column", "pillar"),
    "rod": ("rod", "bar"),
    "bird": ("bird", "toy bird"),
    "bird_simple": ("bird", "toy bird"),
    "compound": ("object", "lump", "shape"),
    "slender": ("bar", "stick", "rod"),
    "duck": ("duck", "rubber-duck shape"),
    "torus": ("ring", "donut"),
}


def object_noun(shape: str, k: int = 0) -> str:
    """The ``k``-th (cyclic) noun of a shape."""
    names = _OBJECT.get(shape, ("object",))
    return names[k % len(names)]


def motion_group(m: Mapping[str, float]) -> str | None:
    """The motion group of a clip from its measures, or None when none fits with a margin.

    ``m``: :func:`~motionphysics.priors.motion_data.motion_measures` plus ``granular``
    (1.0 for sand: "crumbles" is the granular word for a collapse). Ratios are over the
    first frame; ``deform`` is rotation-invariant (distance from the best rigid motion
    over the object size), so a tumbling rigid object is not read as squashed.

    - flow (``spread > 1.5`` or ``final_height < 0.45``, with ``deform > 0.15``):
      granular and at rest (``late_speed < 0.05``) -> ``crumbles``; else ``splashes``
      when it spread wide (``max_spread > 2.0``) and low (``min_height < 0.35``);
      ``oozes`` when the spread stayed moderate (``spread < 1.9``, ``min_height >
      0.3``) and it is still creeping (``late_speed > 0.01``);
    - solids (``spread < 1.5``, not granular): ``bounces_high`` (``rebound > 0.35``,
      ``deform < 0.05``); ``squashes_flat`` (``deform > 0.06``, ``rebound < 0.1``);
      ``wobbles`` (``wobble >= 2``, ``max_deform > 0.03``, ``deform < 0.05``,
      ``rebound <= 0.35``); ``barely_bounces`` (``0.06 < rebound < 0.3``,
      ``max_deform < 0.03``, ``deform < 0.03``); ``keeps_shape`` (``rebound < 0.04``,
      ``max_deform < 0.02``).
    """
    r = m["rebound"]
    hf, hmin = m["final_height"], m["min_height"]
    s, smax = m["spread"], m["max_spread"]
    d, dmax, w, late = m["deform"], m["max_deform"], m["wobble"], m["late_speed"]
    granular = bool(m.get("granular", 0.0))
    if (s > 1.5 or hf < 0.45) and d > 0.15:
        if granular:
            return "crumbles" if late < 0.05 else None
        if smax > 2.0 and hmin < 0.35:
            return "splashes"
        if s < 1.9 and hmin > 0.3 and late > 0.01:
            return "oozes"
        return None
    if granular:
        return "crumbles" if d > 0.1 and late < 0.05 else None
    if s >= 1.5:
        return None
    if r > 0.35 and d < 0.05:
        return "bounces_high"
    if d > 0.06 and r < 0.1:
        return "squashes_flat"
    if w >= 2 and dmax > 0.03 and d < 0.05 and r <= 0.35:
        return "wobbles"
    if 0.06 < r < 0.3 and dmax < 0.03 and d < 0.03:
        return "barely_bounces"
    if r < 0.04 and dmax < 0.02:
        return "keeps_shape"
    return None


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def caption_clip(
    measures: Mapping[str, float],
    cls: str,
    shape: str,
    rng: np.random.Generator,
    *,
    held_out: bool = False,
    with_material: bool | None = None,
    with_firmness: bool = True,
) -> tuple[str, str | None]:
    """One random caption for a clip -> (text, motion group or None).

    ``measures``: :func:`motion_measures` of the clip; ``cls``, ``shape``: its material
    class and shape; ``held_out`` picks from :data:`HELD_OUT`. A solid's caption names
    its :func:`firmness` half of the time ("a stiff rubber ball bounces high", "a soft
    cube wobbles"); ``with_firmness=False`` never does.
    """
    m = dict(measures)
    m["granular"] = 1.0 if cls == "sand" else 0.0
    group = motion_group(m)
    if group is None:
        phrases: Sequence[str] = NEUTRAL
    else:
        phrases = HELD_OUT[group] if held_out else training_phrasings(group)
    phrase = phrases[int(rng.integers(len(phrases)))]
    obj = object_noun(shape, int(rng.integers(4)))
    if with_material is None:
        with_material = bool(rng.random() < 0.6)
    if with_material:
        mats = _MATERIAL[cls]
        noun = f"{mats[int(rng.integers(len(mats)))]} {obj}"
    else:
        noun = obj
    form = int(rng.integers(3))
    firm = firmness(m, group)
    if firm is not None and with_firmness:
        words = FIRMNESS[firm]
        word = words[int(rng.integers(len(words)))]
        if rng.random() < 0.5:
            noun = f"{word} {noun}"
    if form == 0:
        text = f"{_article(noun)} {noun} {phrase}"
    elif form == 1:
        text = f"the {noun} {phrase}"
    else:
        text = f"{_article(noun).capitalize()} {noun} is dropped and {phrase}"
    return text, group


def group_prompt(group: str, shape: str, k: int = 0, *, held_out: bool = True) -> str:
    """The ``k``-th evaluation prompt of ``group`` for a ``shape`` (no material noun)."""
    table = HELD_OUT if held_out else TRAIN
    phrases: Sequence[str] = table[group]
    obj = object_noun(shape, 0)
    return f"{_article(obj)} {obj} {phrases[k % len(phrases)]}"


# ---- contrasting prompts (``negative_prompt: auto``) ---------------------------------

OPPOSITE: dict[str, str | None] = {
    "bounces_high": "squashes_flat",
    "barely_bounces": "bounces_high",
    "wobbles": None,
    "splashes": "oozes",
    "oozes": "splashes",
    "keeps_shape": "squashes_flat",
    "crumbles": "keeps_shape",
    "squashes_flat": "bounces_high",
}
"""The motion group a prompt of each group is contrasted with (None: the unconditional
prompt ``""``). Squashes flat and barely bounces are contrasted with the high bounce, the
motion the pixel prior (since removed) knew best (the largest of the solid groups in its
data): with it, against "keeps its shape" a soft prompt pushed E up on the real donut
capture, as "bounces high" did.

A wobble has no one opposite: it sits between two failures, too stiff to swing and too
soft to come back to its shape, and a fixed opposite pushes from one side only. Against
"bounces high" the motion prior made a jelly that already wobbled softer, and eval's
motion adherence fell on 2 of 3 resolved objects (capsule 0.779 -> 0.726, duck 0.413 ->
0.316, 4 iterations); against the unconditional prompt it rose on all 3 (ring 0.400 ->
0.697, capsule 0.779 -> 0.857, duck 0.413 -> 0.580; BENCHMARKS.md, "The embedded motion
prior"), and "soft, wobbly" still lowers E from a stiff start.

Keeping its shape is contrasted with losing it for good ("squashes and stays flat"). Against
a wobble (the first choice, never measured) "a hard clay ball keeps its shape" left the
clay's yield stress where it started (2e4 -> 1.99e4 Pa, 12 iterations); against the
squash it rose on the ball, the duck and the real ring (3.48e4 / 3.49e4 / 3.44e4)."""

MIN_MOTION_SIMILARITY = 0.45
"""Cosine similarity (MiniLM, mean-pooled) below which a prompt makes no motion claim of
any group (then there is nothing to contrast it with)."""

_VERBS = {"is", "are", "hits", "falls", "drops", "lands", "stays", "keeps", "flows", "moves",
          "gets", "goes", "comes", "will", "does", "was", "then", "and",
          # third-person motion verbs and the adverbs that open a predicate ("Honey drips
          # slowly", "A blob of molasses slowly spreads out")
          "drips", "springs", "spreads", "slides", "rolls", "pours", "spills", "slumps",
          "sags", "leaps", "jumps", "rebounds", "squashes", "flattens", "dents", "breaks",
          "shatters", "deforms", "settles", "tumbles", "topples", "sinks", "stretches",
          "bends", "sways", "plops", "thuds", "smashes", "crashes", "collapses", "tips",
          "rocks", "quivers", "trembles", "shakes", "vibrates", "runs", "creeps", "bursts",
          "splats", "sloshes", "melts", "crumbles", "bounces", "wobbles", "jiggles",
          "splashes", "oozes", "remains", "wiggles", "trickles", "gushes", "hops", "seeps",
          "flops", "squishes", "squelches", "glides", "skids", "cracks", "sticks",
          "slowly", "quickly", "gently", "suddenly"}  # fmt: skip


def _sentence_embeddings(texts: list[str]):
    """Mean-pooled, unit-norm MiniLM sentence embeddings [N, 384] (the prior's encoder)."""
    from motionphysics.language.text import sentence_embeddings

    return sentence_embeddings(texts, max_tokens=24)


@functools.cache
def _verb_starts() -> frozenset[str]:
    """Words that begin a predicate: the first words of every phrasing, and _VERBS."""
    phrases = [p for g in GROUPS for p in (*TRAIN[g], *HELD_OUT[g], *READING_EXTRA[g])]
    return frozenset(p.split()[0] for p in [*phrases, *READING_NEUTRAL]) | _VERBS


def _split(prompt: str) -> tuple[str, str]:
    """(subject, predicate): the words of ``prompt`` before its first verb and the rest;
    ("the object", "") when no verb is found."""
    starts = _verb_starts()
    words = prompt.strip().rstrip(".!").split()
    for i, w in enumerate(words):
        if i > 0 and w.lower().strip(",;") in starts:
            return " ".join(words[:i]).rstrip(",;"), " ".join(words[i:])
    # no verb we know: the first word ending in "s" that follows a noun ("The jelly
    # wiggles"), not an article, adjective slot or "of" ("a glass ball", "of molasses")
    for i, w in enumerate(words):
        prev = words[i - 1].lower() if i > 0 else ""
        if i > 1 and w.lower().endswith("s") and not w.lower().endswith("ss"):
            if prev not in ("a", "an", "the", "of", "some", "two", "three", "its", "their"):
                return " ".join(words[:i]).rstrip(",;"), " ".join(words[i:])
    return "the object", ""


def prompt_clauses(prompt: str, *, whole_if_no_verb: bool = False) -> list[str]:
    """The clauses of the prompt's predicate (what it says the thing does: the words from
    its first verb on), split at commas, "and", "then", "but", "while". No clauses when no
    verb is found, unless ``whole_if_no_verb`` (then the whole prompt's)."""
    import re

    _, pred = _split(prompt)
    if not pred and whole_if_no_verb:
        pred = prompt.strip().rstrip(".!")
    split = r",|;|\band\b|\bthen\b|\bbut\b|\bwhile\b"
    return [c.strip() for c in re.split(split, pred) if c.strip()]


def prompt_subject(prompt: str) -> str:
    """What the prompt is about: its words before the first verb ("A soft, wobbly rubber
    capsule" of "A soft, wobbly rubber capsule is dropped and squashes"), the whole prompt
    when no verb is found ("a bouncy ball"), ``""`` for ``""``."""
    if not prompt.strip():
        return ""
    subject, pred = _split(prompt)
    return subject if pred else prompt.strip().rstrip(".!")


def prompt_motion_group(prompt: str, exclude: Collection[str] = ()) -> tuple[str | None, float]:
    """The motion group whose phrasings (training, held-out and :data:`READING_EXTRA`) a
    clause of the prompt's predicate (what it says the thing does; clauses split at commas,
    "and", "then", "but", "while") is closest to, and that similarity. A clause counts
    only when its closest group is at least MIN_MOTION_SIMILARITY and closer than every
    :data:`READING_NEUTRAL` phrase ("is dropped", "hits the ground"). None when no clause
    counts, or the prompt has no verb. Groups in ``exclude`` are not candidates (a motion
    the material cannot show, e.g. "crumbles", the granular word, for a fluid)."""
    group, sim, _ = prompt_motion_reading(prompt, exclude=exclude)
    return group, sim


def prompt_motion_reading(
    prompt: str,
    *,
    held_out_anchors: bool = True,
    whole_if_no_verb: bool = False,
    exclude: Collection[str] = (),
) -> tuple[str | None, float, str]:
    """:func:`prompt_motion_group` with the clause that decided: ``(group, similarity,
    clause)``. ``held_out_anchors=False`` compares with the training phrasings only (what
    the kb's motion reading uses, so held-out phrasings stay unseen by everything that
    reads a prompt); ``whole_if_no_verb`` reads the whole prompt when no verb splits it."""
    clauses = prompt_clauses(prompt, whole_if_no_verb=whole_if_no_verb)
    if not clauses:
        return None, 0.0, ""
    table = {
        g: (*TRAIN[g], *READING_EXTRA[g], *(HELD_OUT[g] if held_out_anchors else ()))
        for g in GROUPS
    }
    phrases = [(g, p) for g in GROUPS for p in table[g]]
    emb = _sentence_embeddings(clauses + [p for _, p in phrases] + list(READING_NEUTRAL))
    k = len(clauses)
    sims = emb[:k] @ emb[k:].T  # [clauses, phrases + neutral]
    found: tuple[str | None, float, str] = (None, 0.0, "")
    for c in range(k):
        row = sims[c].tolist()
        best: dict[str, float] = {}
        for (g, _), v in zip(phrases, row[: len(phrases)], strict=True):
            if g not in exclude:
                best[g] = max(best.get(g, -1.0), v)
        group = max(best, key=best.get)
        if best[group] >= MIN_MOTION_SIMILARITY and best[group] > max(row[len(phrases) :]):
            if best[group] > found[1]:
                found = (group, best[group], clauses[c])
    return found


HEAP_SIDES: dict[str, tuple[str, ...]] = {
    "steep": (
        "stays a tall, steep heap",
        "keeps a steep slope",
        "stands tall and steep",
        "holds a steep cone",
    ),
    "flat": (
        "collapses and spreads out flat",
        "spreads into a low, flat layer",
        "slumps flat",
        "spreads thin across the floor",
        "spreads into a low mound",
    ),
    "neither": (
        "crumbles into a heap",
        "settles in a heap",
        "falls apart into a mound",
        "collapses into a pile",
        "disintegrates into a pile",
    ),
}
"""How a pile of grains can be asked to settle: a tall, steep heap, a flat spread, or
neither (just "a heap", "a mound": the words every crumbling pile gets). Every pile
"crumbles" (one motion group), so the group cannot say which; each clause of the prompt is
read against these phrasings (:func:`heap_side`)."""

HEAP_MARGIN = 0.05
"""A clause reads as "steep" or "flat" only when it is this much closer (cosine, MiniLM)
to that side's phrasings than to both others'."""


def heap_side(prompt: str) -> str | None:
    """``"steep"``, ``"flat"`` or None: which way a prompt asks a pile to settle, from the
    clause that reads most clearly as one side of :data:`HEAP_SIDES`; None when every
    clause is nearest to "neither", below MIN_MOTION_SIMILARITY, or within
    :data:`HEAP_MARGIN` of another side."""
    clauses = prompt_clauses(prompt)
    if not clauses:
        return None
    anchors = [(side, p) for side, ps in HEAP_SIDES.items() for p in ps]
    emb = _sentence_embeddings(clauses + [p for _, p in anchors])
    k = len(clauses)
    found, gap = None, HEAP_MARGIN
    for row in (emb[:k] @ emb[k:].T).tolist():
        best = dict.fromkeys(HEAP_SIDES, -1.0)
        for (side, _), v in zip(anchors, row, strict=True):
            best[side] = max(best[side], v)
        for side in ("steep", "flat"):
            lead = best[side] - max(v for o, v in best.items() if o != side)
            if best[side] >= MIN_MOTION_SIMILARITY and lead >= gap:
                found, gap = side, lead
    return found


def contrast_prompt(prompt: str) -> str:
    """A description of the opposite motion with the prompt's subject: "A stiff ring
    bounces high" -> "A stiff ring squashes and stays flat". "" when the prompt makes no
    motion claim (:func:`prompt_motion_group`) or claims a wobble (:data:`OPPOSITE`).

    A pile that crumbles is contrasted with keeping its shape, unless the prompt asks it to
    stay a tall, steep heap (:func:`heap_side`): then the opposite is a flat spread
    ("splashes"). Against "keeps its shape" every sand prompt pushed the friction angle
    down, "coarse gravel stays a tall, steep heap" as much as "fine sand spreads out flat"
    (BENCHMARKS.md, "The embedded motion prior")."""
    group, _ = prompt_motion_group(prompt)
    if group is None or OPPOSITE[group] is None:
        return ""
    opposite = OPPOSITE[group]
    if group == "crumbles" and heap_side(prompt) == "steep":
        opposite = "splashes"
    return f"{_split(prompt)[0]} {TRAIN[opposite][0]}"
