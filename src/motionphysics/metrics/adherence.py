"""Motion adherence: does the simulated motion do what the prompt's motion words say?

The paper names the lack of a prompt-adherence metric that sees temporal dynamics as
future work (CLIPSIM scores frames one at a time; OC sees 8 frames of appearance).
This score needs no model weights: it reads the prompt's motion words and checks the
behaviours they imply against measurements of the trajectory alone, the ones a viewer
sees: the squash at impact (its peak, not only the final shape), the rebound, how much
of a shape change is undone, how far and how fast it spreads, whether it oscillates
(amplitude, frequency, and not a single droop), whether it stays in one piece.

1. **Cues** (:data:`CUES`): word patterns (stems, so "bounce", "bounces", "bouncing",
   "bouncy" all match) for motions (bounce / rebound, splash / spread / flow, keep
   shape / rigid, wobble / jiggle, vibrate (a small oscillation), squash, flatten,
   stay / permanent, collapse, crumble / fall apart, heap / pile, break apart, ooze /
   creep, slowly, gently (slow and small), fall / drop / land, bend, roll / slide,
   spin, rest, deform) and, with half weight, for materials that imply a motion
   (rubber -> rebound, water -> spread, sand -> heap, clay -> stays deformed, honey ->
   slow ...). A cue that completes another verb ("crumbles into a heap") weighs half.
   A negation up to three words before a cue ("does not bounce", "without spreading")
   flips it. A bounce is graded by the words around it: "barely", "a little",
   "feebly" ask for a small rebound (:data:`WEAK`), "high", "very", "right back" for a
   high one (:data:`STRONG`).
2. **Behaviours** (:data:`BEHAVIOURS`): each cue expects some behaviours to be high or
   low, with a weight (1 for what the words say, 0.5 for what they imply). Cues that
   agree add up (weight capped at 1); cues that disagree cancel.
3. **Measurements** (:func:`measure`), dimensionless so they transfer across scene
   sizes: L is the object's largest initial extent, h the height above the floor,
   c the mass centroid, sqrt(L / g) the time unit (all from ``trajectory.npz``:
   ``x [T, P, 3]`` m, ``t [T]`` s, optional ``v [T, P, 3]`` m/s, ``mass [P]`` kg and
   ``gravity [3]`` m/s^2).
4. **Score** of one behaviour: a logistic ramp ``1 / (1 + exp(-(m - threshold) /
   width))`` for "high" (one minus it for "low"; a band behaviour multiplies a rising
   and a falling ramp), so 0.5 at the threshold. The prompt's score is the weighted
   HARMONIC mean of the terms it asked for (each floored at :data:`SCORE_FLOOR`): every
   claim must hold, and one the motion plainly contradicts ("spreads slowly" on a
   spread that covered the floor in half a second) sinks the score instead of being
   averaged away (the weighted arithmetic mean is kept as ``score_mean``). Salient
   motions the prompt did not ask for (:data:`UNMENTIONED`: a bounce, a spread, a
   wobble, a roll, a turn) multiply it by their "low" score to a small power. Each term
   is reported with its expected direction, measured value, threshold, score and a
   one-line explanation (``"squashes: peak squash 26 % -> 0.99"``).

The thresholds are physical judgements, documented beside each behaviour (e.g. a
bounce is a centroid rise of at least 15 % of the fall, a squash a loss of at least
10 % of the height at some instant). No optimiser fitted them, but they and the word
lists were adjusted while the confusion matrices of labelled trajectories were
watched: hand-made ones per motion word (:mod:`motionphysics.evaluation.adherence_calibration`) and the motion
prior's simulated clips, whose group is their measured motion (the training clips for
adjusting, the held-out clips for the published check: BENCHMARKS.md, "Motion
adherence: words x behaviours"). This module must not read files or run simulations.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = [
    "BEHAVIOURS",
    "CUES",
    "SCORE_FLOOR",
    "UNMENTIONED",
    "behaviour_score",
    "floor_height",
    "measure",
    "motion_adherence",
    "parse_prompt",
]


@dataclass(frozen=True)
class Behaviour:
    """One observable behaviour: what is measured, and where "high" begins."""

    name: str
    measure: str
    """Key of :func:`measure`'s output."""
    threshold: float
    width: float
    """Logistic width: the score is 0.27 / 0.73 one width below / above the threshold."""
    doc: str
    upper: float | None = None
    """A band: "high" means between ``threshold`` and ``upper`` (both edges ``width``)."""


BEHAVIOURS: dict[str, Behaviour] = {
    b.name: b
    for b in (
        Behaviour(
            "fall",
            "fall_distance",
            0.5,
            0.15,
            "centroid drop below its start, in object sizes L (a drop over half its own size)",
        ),
        Behaviour(
            "rebound",
            "rebound",
            0.15,
            0.05,
            "rise of the centroid after a low point over the fall before it (fall floored at"
            " 0.2 L): a bounce rises at least 15 % of its fall",
        ),
        Behaviour(
            "rebound_high",
            "rebound",
            0.35,
            0.06,
            'the same rebound ratio; a HIGH bounce ("bounces high", "very bouncy")'
            " rises over a third of its fall",
        ),
        Behaviour(
            "rebound_small",
            "rebound",
            0.04,
            0.015,
            "the same rebound ratio in a band, 4 % to 33 % of the fall: a small bounce"
            ' ("barely bounces", "rebounds feebly") is seen, but low',
            upper=0.33,
        ),
        Behaviour(
            "bounce_seen",
            "rebound",
            0.08,
            0.03,
            "the same rebound ratio at a lower bar: a bounce a viewer notices although the"
            " prompt did not ask for one (rises 8 % of its fall)",
        ),
        Behaviour(
            "spread",
            "spread",
            0.12,
            0.04,
            "growth of the RMS horizontal radius about the centroid, final minus initial, in L"
            " (0.12 L: a ball's radius grows by over a third)",
        ),
        Behaviour(
            "heap",
            "aspect",
            0.08,
            0.025,
            "final height over final horizontal diameter (high: a mound, e.g. 0.3 for a 32 deg"
            " sand cone; low: a sheet or puddle)",
        ),
        Behaviour(
            "tall",
            "aspect",
            0.6,
            0.2,
            "final height over final horizontal diameter (LOW: wider than tall, squashed flat)",
        ),
        Behaviour(
            "collapse",
            "flatten",
            0.5,
            0.1,
            "loss of vertical extent, 1 - final / initial (a collapse loses over half its height)",
        ),
        Behaviour(
            "bend",
            "bend_deg",
            10.0,
            3.0,
            "largest final angle between the rotations of 6 slabs cut across the rest"
            " shape's long axis [deg]",
        ),
        Behaviour(
            "recovery",
            "recovery",
            0.4,
            0.12,
            "how much of the largest shape change is undone by the end: (max - final) /"
            " max(max, 0.02) of the RMS residual; 1 when the shape never visibly changed (its"
            " most moved part under 2 % of L)",
        ),
        Behaviour(
            "flatten",
            "flatten",
            0.25,
            0.08,
            "loss of vertical extent at the END: 1 - final / initial extent along up",
        ),
        Behaviour(
            "squash",
            "peak_squash",
            0.1,
            0.03,
            "PEAK squash over the clip: the largest loss of extent along an axis of the rest"
            " pose, after undoing the rotation (a visible squash takes over 10 % of the height)",
        ),
        Behaviour(
            "deform",
            "shape_change",
            0.06,
            0.02,
            "final shape change after removing rigid motion: RMS Procrustes residual / L",
        ),
        Behaviour(
            "deform_any",
            "max_tip_change",
            0.05,
            0.015,
            "largest shape change over the clip at its largest place (99th percentile of the"
            " particles' distance from the best rigid motion / L): a bar bent at one end"
            " changed its shape although most of it did not",
        ),
        Behaviour(
            "large_shape",
            "max_tip_change",
            0.04,
            0.012,
            "largest shape change at its largest place over the clip: 99th percentile of the"
            " particles' distance from the best rigid motion, in L (LOW: a gentle, small"
            " motion; a rod that droops to the floor moves its tip over 10 % of L)",
        ),
        Behaviour(
            "oscillate",
            "osc_swings",
            2.5,
            0.75,
            "swings of the shape (RMS or 99th-percentile Procrustes residual, or the strain"
            " along the rest axis that changes most, or the angle between a slender body's end"
            " slabs (signed) in units of 100 deg with swings over 2 deg: all"
            " rotation-free) in one decaying train from its first swing on: each over 1 % of"
            " L and over half the swing before it, so one droop or one squash followed by"
            " small wiggles is not an oscillation (3 swings: one and a half periods)",
        ),
        Behaviour(
            "fast",
            "pace",
            0.2,
            0.06,
            "mean particle speed after the first contact with the floor (the whole clip"
            " without one) / sqrt(g L): the pace of the motion the prompt describes, not of"
            " the fall before it (LOW: oozing, creeping, gentle)",
        ),
        Behaviour(
            "moving_at_end",
            "final_speed",
            0.05,
            0.02,
            "mean particle speed in the last 10 % of frames / sqrt(g L) (LOW: settled)",
        ),
        Behaviour(
            "creeping",
            "late_spread",
            0.01,
            0.004,
            "growth of the RMS horizontal radius over the last quarter of the clip, in L:"
            " still spreading at the end, however slowly (an ooze or a slump that has not"
            " stopped; LOW: its shape has come to rest, whatever small vibration is left)",
        ),
        Behaviour(
            "travel",
            "travel",
            0.5,
            0.15,
            "horizontal distance the centroid travels, in L (rolls, slides)",
        ),
        Behaviour(
            "rotate",
            "rotation_deg",
            45.0,
            15.0,
            "rotation of the best-fit rigid motion, final vs initial [deg]",
        ),
        Behaviour(
            "move",
            "max_displacement",
            0.1,
            0.03,
            "largest particle displacement, in L (LOW: stays still)",
        ),
        Behaviour(
            "intact",
            "intact",
            0.9,
            0.03,
            "mass fraction of the largest connected piece at the end, over the same at the"
            " start (links: the shortest of 2.5, 4, 6, 10x the initial median particle"
            " spacing at which the rest shape is one piece): 1 in one piece",
        ),
    )
}

# A cue: regex over the lower-cased prompt (word stems; \b-anchored) -> [(behaviour, +1 high
# / -1 low, weight)]. Motion words weigh 1, what they imply 0.5; material words 0.5.
_H, _L, _ANY = +1, -1, 0  # _ANY: the cue tolerates the behaviour (no unasked-for hint)
CUES: list[tuple[str, str, list[tuple[str, int, float]]]] = [
    # -- motions
    (
        "bounce",
        r"bounc\w*|rebound\w*|spring\w* back|jump\w* (?:right )?back|bounds? back|recoil\w*"
        r"|hops?\b|hopping",
        [("rebound", _H, 1.0), ("spread", _L, 0.5)],
    ),
    (
        "splash",
        r"splash\w*|splatter\w*|spatter\w*|burst\w*",
        # a splash is fast and a liquid goes on spreading thin; grains come to rest
        [
            ("spread", _H, 1.0),
            ("heap", _L, 0.5),
            ("rebound", _L, 0.5),
            ("fast", _H, 0.5),
            ("creeping", _H, 0.5),
        ],
    ),
    (
        "spread",
        r"spread\w*|spill\w*|scatter\w*|puddle\w*|sheet\w*|fans? out|splay\w*|covers? the",
        [("spread", _H, 1.0), ("heap", _L, 0.5)],
    ),
    (
        "flow",
        r"flow\w*|pour\w*|stream\w*|slosh\w*|runs? (?:out|across|over|down)|gush\w*|drain\w*",
        [("spread", _H, 1.0), ("deform", _H, 0.5), ("flatten", _H, 0.5)],
    ),
    (
        "rigid",
        r"rigid\w*|keeps? (?:its|their|the) (?:original )?shape|holds? (?:its|their) (?:shape|form)"
        r"|retains? (?:its|their) shape|maintains? (?:its|their) shape|unchang\w*|undeform\w*"
        r"|stiff\w*|solid\w*|unbreakable|stays? intact|in one piece",
        [("deform_any", _L, 1.0), ("spread", _L, 0.5), ("intact", _H, 0.5)],
    ),
    (
        "deform",
        r"deform\w*|distort\w*|misshapen",
        [("deform_any", _H, 1.0), ("intact", _H, 0.5)],
    ),
    (
        "wobble",
        r"wobbl\w*|jiggl\w*|wiggl\w*|oscillat\w*|jelly-like|sway\w*|shak\w*|springy|bobs?"
        r"|bobbing|quiver\w*|trembl\w*|shiver\w*",
        # a wobbling body's landing hop is part of its wobble: no unasked-bounce hint
        [("oscillate", _H, 1.0), ("deform", _L, 0.5), ("bounce_seen", _ANY, 0.0)],
    ),
    (
        "vibrate",
        r"vibrat\w*|judder\w*|jitter\w*|hum\b|humming|buzz\w*",
        # a vibration is a SMALL oscillation about the shape (not a droop and a flop)
        [
            ("oscillate", _H, 1.0),
            ("deform", _L, 0.5),
            ("large_shape", _L, 0.5),
            ("bounce_seen", _ANY, 0.0),
        ],
    ),
    (
        "squash",
        r"squash\w*|squish\w*|(?:pressed|pushed|squeezed|crushed) flat|crush\w*|compress\w*"
        r"|smash\w*|dent\w*",
        # (a squash bulges sideways: no claim on the spread; a splash is not a squash by
        # its fall into a sheet, see "flat")
        [("squash", _H, 1.0), ("intact", _H, 0.5)],
    ),
    (
        "flat",
        r"flatten\w*|pancake\w*|flat\b",
        [("flatten", _H, 1.0), ("tall", _L, 0.5)],
    ),
    (
        "stay",
        r"permanent\w*|stays? (?:bent|flat|deformed|squashed|dented|that way|down)"
        r"|keeps? (?:its|their|the) (?:new|deformed|flattened|squashed|bent|dented) (?:shape|form)"
        r"|keeps? the dent|holds? (?:its|their|the) new shape|remains? (?:bent|flat|deformed|dented)"
        r"|plastically|does ?n[o']t (?:spring|bounce|recover) back|never recovers"
        r"|does ?n[o']t recover",
        [("recovery", _L, 1.0), ("creeping", _L, 0.5), ("intact", _H, 0.5)],
    ),
    (
        "recover",
        r"recover\w*|returns? to (?:its|their) (?:original )?shape|springs? back"
        r"|regains? (?:its|their) shape|restor\w*",
        [("recovery", _H, 1.0)],
    ),
    (
        "bend",
        r"bend\w*|bent|buckl\w*|curl\w*|fold\w*|twist\w*|warp\w*|kink\w*|sag\w*|droop\w*",
        [("bend", _H, 1.0), ("spread", _L, 0.5), ("intact", _H, 0.5)],
    ),
    (
        "collapse",
        r"collaps\w*|slump\w*|caves? in|topple\w*|gives? way|subsid\w*",
        [("collapse", _H, 1.0), ("spread", _H, 0.5), ("moving_at_end", _L, 0.5)],
    ),
    (
        "crumble",
        r"crumbl\w*|disintegrat\w*|falls? (?:apart|to pieces)|breaks? down|comes? apart",
        [
            ("collapse", _H, 1.0),
            ("intact", _L, 1.0),
            ("spread", _H, 0.5),
            ("moving_at_end", _L, 0.5),
        ],
    ),
    (
        "heap",
        r"heap\w*|piles? up|pil(?:e|es|ed|ing)\b|mound\w*|cone\b|stack\w* up|build\w* up",
        [("heap", _H, 1.0), ("flatten", _H, 0.5), ("moving_at_end", _L, 0.5)],
    ),
    (
        "break",
        r"break\w* (?:apart|up|into|in two)|broken|shatter\w*|fragment\w*|splinter\w*"
        r"|snaps? (?:in two|apart)|tears? apart|splits? (?:apart|in two|into)",
        [("intact", _L, 1.0)],
    ),
    (
        "ooze",
        r"ooz\w*|creep\w*|seep\w*|drip\w*|trickl\w*",
        # an ooze is one mass creeping, not grains trickling apart
        [("fast", _L, 1.0), ("creeping", _H, 0.5), ("intact", _H, 0.5), ("spread", _H, 0.5)],
    ),
    (
        "slow",
        r"slow\w*|gradual\w*|sluggish\w*|viscous\w*|thick\w*|languid\w*|lazil\w*",
        [("fast", _L, 1.0)],
    ),
    (
        "gentle",
        r"gentl\w*|softly|lightly|subtl\w*|faint\w*|slight\w*",
        # gentle: slow AND small
        [("fast", _L, 1.0), ("large_shape", _L, 0.5)],
    ),
    (
        "fast",
        r"quick\w*|rapid\w*|fast\b|violent\w*|explosive\w*|sudden\w*|hurl\w*|shoots?\b",
        [("fast", _H, 1.0)],
    ),
    (
        "fall",
        r"fall(?!\w* (?:apart|to pieces))\w*|fell\b|drop\w*|dropped|tumbl\w*|plummet\w*|plung\w*"
        r"|descend\w*|lands?\b|landing"
        r"|hits? the (?:ground|floor|table|surface)|thrown down",
        [("fall", _H, 1.0)],
    ),
    (
        "roll",
        r"roll\w*|slid\w*|glid\w*|skid\w*|travel\w*",
        [("travel", _H, 1.0)],
    ),
    (
        "spin",
        r"spin\w*|spun\b|rotat\w*|twirl\w*|whirl\w*|turns? over|flips?\b|flipping",
        [("rotate", _H, 1.0)],
    ),
    (
        "still",
        r"stays? still|motionless|stationary|does ?n[o']t move|at rest|unmoved|stands? still",
        [("move", _L, 1.0)],
    ),
    # -- materials (what the material itself implies, half weight)
    (
        "elastic material",
        r"rubber\w*|elastic\w*|trampoline|balloon\w*",
        [("rebound", _H, 0.5)],
    ),
    (
        "liquid material",
        r"water\w*|liquid\w*|fluid\w*|juice|milk|wine|coffee|oil\b|rain\w*|droplet\w*",
        [("spread", _H, 0.5), ("heap", _L, 0.5), ("creeping", _H, 0.5)],
    ),
    (
        "granular material",
        r"sand\w*|grain\w*|granul\w*|gravel|powder\w*|soil|dirt|sugar|salt|flour|snow\w*",
        [("heap", _H, 0.5), ("flatten", _H, 0.5)],
    ),
    (
        "plastic material",
        r"clay|plasticine|putty|dough\w*|playdough|play-doh|modeling|modelling|wax\b",
        [("deform", _H, 0.5), ("rebound", _L, 0.5)],
    ),
    (
        "metal material",
        r"metal\w*|steel|iron|alumin\w*|copper|brass|tin\b|wire",
        [("spread", _L, 0.5), ("flatten", _L, 0.5)],
    ),
    (
        "gel material",
        r"jell\w*|gelatin\w*|pudding|custard|tofu",
        [("oscillate", _H, 0.5)],
    ),
    (
        "viscous material",
        r"honey|syrup|molasses|treacle|jam\b|goo\b|slime|lava|tar\b|glue",
        [("fast", _L, 0.5), ("intact", _H, 0.5)],
    ),
    (
        "paste material",
        r"toothpaste|paste\b|cream\w*|mud\w*|ketchup|mayonnaise|cement|batter",
        [("heap", _H, 0.5), ("spread", _L, 0.5)],
    ),
]
_COMPILED = [(name, re.compile(rf"\b(?:{pat})"), eff) for name, pat, eff in CUES]
_NEGATORS = {"not", "no", "never", "without", "nor", "cannot", "neither"}
_NEG_SUFFIX = ("n't", "n’t")
WEAK = frozenset(
    "barely hardly slightly little tiny feebly feeble weak weakly small faint faintly".split()
)
"""Words within three before or four after a bounce that ask for a SMALL rebound."""
STRONG = frozenset("high higher highly very strongly right hard lot tall".split())
"""Words within three before or four after a bounce that ask for a HIGH rebound."""


def _negated(text: str, start: int) -> bool:
    before = re.findall(r"[\w'’]+", text[:start])[-3:]
    return any(w in _NEGATORS or w.endswith(_NEG_SUFFIX) or w in ("dont", "doesnt") for w in before)


def _complement(text: str, start: int) -> bool:
    """Whether the cue at ``start`` is the complement of another verb ("into a heap",
    "in a mound", "to a flat shape"): the two or three words before it are a
    preposition and an article (and maybe one adjective)."""
    before = re.findall(r"[\w']+", text[:start])[-3:]
    return any(
        len(before) >= k and before[-k] in ("into", "in", "to") and before[-k + 1] in ("a", "an")
        for k in (2, 3)
    )


def _grade(text: str, start: int, end: int) -> str | None:
    """The intensity words around a bounce: "weak", "strong" or None."""
    near = re.findall(r"[\w']+", text[:start])[-3:] + re.findall(r"[\w']+", text[end:])[:4]
    if any(w in WEAK for w in near):
        return "weak"
    if any(w in STRONG for w in near):
        return "strong"
    return None


def parse_prompt(prompt: str) -> dict[str, Any]:
    """The cues found in ``prompt`` and the behaviours they expect.

    Returns ``{"cues": [{"cue", "words", "negated"}], "expected": {behaviour: (sign,
    weight)}, "words": {behaviour: [the prompt's words that asked for it]}}`` where sign
    is +1 (high) or -1 (low) and weight in (0, 1]. "does not bounce back" matches both
    "bounce" and "recover" (both negated), as it should; "barely bounces" asks for a
    small rebound (``rebound_small``), "bounces high" for a high one (``rebound_high``).
    """
    text = " ".join(str(prompt).lower().replace("’", "'").split())
    found: list[dict[str, Any]] = []
    acc: dict[str, float] = {}
    words: dict[str, list[str]] = {}
    tolerated: set[str] = set()
    for name, rx, effects in _COMPILED:
        for m in rx.finditer(text):
            neg = _negated(text, m.start())
            cue = {"cue": name, "words": m.group(0), "negated": neg}
            if _complement(text, m.start()):
                # "crumbles into a heap": the heap is where the verb ends, half a claim
                effects = [(b, sg, 0.5 * w) for b, sg, w in effects]
                cue["complement"] = True
            if name == "bounce" and not neg:
                grade = _grade(text, m.start(), m.end())
                if grade == "weak":
                    effects = [("rebound_small", _H, 1.0)]
                elif grade == "strong":
                    effects = [("rebound_high", _H, 1.0), ("spread", _L, 0.5)]
                cue["grade"] = grade
            found.append(cue)
            for beh, sign, w in effects:
                if sign == _ANY:
                    tolerated.add(beh)
                    continue
                # a negated motion says "not this", not "the opposite": its implications
                # (half weight) are dropped, the main behaviour is flipped
                if neg and w < 1.0:
                    continue
                acc[beh] = acc.get(beh, 0.0) + (-sign if neg else sign) * w
                said = ("not " if neg else "") + m.group(0)
                if said not in words.setdefault(beh, []):
                    words[beh].append(said)
            break  # one match per cue is enough: repeating a word does not weigh more
    expected = {b: (1 if v > 0 else -1, min(1.0, abs(v))) for b, v in acc.items() if abs(v) > 1e-9}
    return {
        "cues": found,
        "expected": expected,
        "words": {b: words[b] for b in expected},
        "tolerated": sorted(tolerated),
    }


# ----------------------------------------------------------------------------------- measurements
def floor_height(x: np.ndarray, up: np.ndarray) -> float:
    """Floor height along ``up`` when no collider is known: the lowest point any particle
    reaches over the clip (0.1th percentile per frame, minimum over frames) [m]."""
    h = np.asarray(x, dtype=np.float64) @ up
    return float(np.percentile(h, 0.1, axis=1).min())


def _kabsch(
    p: np.ndarray, q: np.ndarray, w: np.ndarray, *, tip: bool = False
) -> tuple[np.ndarray, float] | tuple[np.ndarray, float, float]:
    """Best rotation R mapping centred p onto centred q (weights w); returns (R, rms
    residual), and with ``tip`` also the 99th percentile of the particle residuals (the
    free end of a bending rod, where the RMS is dominated by its clamped part)."""
    pc = p - (w[:, None] * p).sum(0) / w.sum()
    qc = q - (w[:, None] * q).sum(0) / w.sum()
    H = (w[:, None] * pc).T @ qc
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    r = qc - pc @ R.T
    rr = (r * r).sum(1)
    rms = float(np.sqrt((w * rr).sum() / w.sum()))
    if tip:
        return R, rms, float(np.sqrt(np.percentile(rr, 99)))
    return R, rms


def _reversals(signal: np.ndarray, hysteresis: float) -> int:
    """Number of direction reversals of ``signal`` larger than ``hysteresis``."""
    return max(0, len(_extrema(signal, hysteresis)) - 2)


def _extrema(signal: np.ndarray, hysteresis: float) -> list[tuple[int, float]]:
    """The start, the turning points (reversals larger than ``hysteresis``) and the last
    extreme of ``signal``, as (frame, value)."""
    y0 = float(signal[0])
    pts = [(0, y0)]
    direction, ext_i, ext = 0, 0, y0
    for i, v in enumerate(signal[1:], start=1):
        v = float(v)
        if direction == 0:
            if abs(v - y0) > hysteresis:
                direction, ext_i, ext = (1 if v > y0 else -1), i, v
        elif direction > 0:
            if v > ext:
                ext_i, ext = i, v
            elif ext - v > hysteresis:
                pts.append((ext_i, ext))
                direction, ext_i, ext = -1, i, v
        else:
            if v < ext:
                ext_i, ext = i, v
            elif v - ext > hysteresis:
                pts.append((ext_i, ext))
                direction, ext_i, ext = 1, i, v
    if direction != 0:
        pts.append((ext_i, ext))
    return pts


VISIBLE_SWING = 0.03
"""Smallest swing (peak to peak, in L for the shape signals, in strain for the strain
signal) of an oscillation the prompt did not ask for that counts against it: 3 % of L is
9 mm on a 0.3 m object, several pixels in a video that shows the object whole. Measured on
24 end-to-end runs (BENCHMARKS.md): the unasked jiggles of bouncing solids swing 1-4 % of L
(amplitudes 0.5-1.9 %), the asked wobbles 20-50 % (amplitudes 0.1-0.25)."""
VISIBLE_SWING_ANGLE = 5.0
"""The same for the angle between a slender body's end slabs [deg]."""

DECAY = 0.5
"""Each swing of an oscillation is at least this fraction of the swing before it (a
damping ratio up to about 0.2 between half-periods)."""


def _swing_train(signal: np.ndarray, t: np.ndarray, floor: float) -> dict[str, float]:
    """The oscillation of ``signal`` (see ``BEHAVIOURS["oscillate"]``): the train of swings
    from the first swing over ``floor`` (or from the second when it is over twice the
    first: a precursor of the real excitation) while each is at least :data:`DECAY` of
    the one before -> {swings, amplitude (half the mean swing), frequency_hz}. A rod that
    droops to the floor and lies there makes one big swing and then small ones: a train
    of one."""
    pts = _extrema(signal, floor)
    sw = [abs(pts[k][1] - pts[k - 1][1]) for k in range(1, len(pts))]
    k = next((i for i, s in enumerate(sw) if s >= floor), None)
    if k is None:
        return {"swings": 0.0, "amplitude": 0.0, "frequency_hz": 0.0}
    j = k + 1
    while j < len(sw) and sw[j] >= max(floor, DECAY * sw[j - 1]):
        if sw[j] > sw[j - 1] / DECAY and j == k + 1:
            k = j  # the first swing was a precursor of the real excitation: start there
        j += 1
    n = j - k
    span = float(t[pts[j][0]] - t[pts[k][0]])
    return {
        "swings": float(n),
        "amplitude": 0.5 * float(np.mean(sw[k:j])),
        "frequency_hz": (0.5 * n / span) if span > 0 and n >= 2 else 0.0,
    }


def _pieces(p: np.ndarray, w: np.ndarray, radius: float) -> float:
    """Mass fraction of the largest connected piece of points ``p`` [N, 3] (links shorter
    than ``radius``)."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(p).query_pairs(radius, output_type="ndarray")
    if len(p) < 2:
        return 1.0
    from scipy.sparse import coo_matrix

    n = len(p)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    mass = np.bincount(labels, weights=w)
    return float(mass.max() / w.sum())


def measure(
    traj: dict[str, np.ndarray], *, floor: float | None = None, max_particles: int = 4000
) -> dict[str, Any]:
    """Dimensionless measurements of a trajectory (see :data:`BEHAVIOURS`).

    ``floor``: height of the ground along up [m] (e.g. from the run's surface collider);
    None: :func:`floor_height`. At most ``max_particles`` particles are used (a fixed,
    evenly strided subset) so long runs stay fast.
    """
    from motionphysics.metrics.physical import up_axis

    x = np.asarray(traj["x"], dtype=np.float64)
    t = np.asarray(traj["t"], dtype=np.float64)
    T, P, _ = x.shape
    stride = max(1, P // max_particles)
    x = x[:, ::stride]
    m = (
        np.asarray(traj["mass"], dtype=np.float64).reshape(P)[::stride]
        if "mass" in traj
        else np.ones(x.shape[1])
    )
    m = np.where(m > 0, m, 0.0) + 1e-30
    g_vec = np.asarray(traj.get("gravity", (0.0, 0.0, -9.8)), dtype=np.float64).reshape(3)
    up = up_axis(g_vec)
    g = float(np.linalg.norm(g_vec)) or 9.8
    h = x @ up  # [T, P]
    floor_src = "given"
    if floor is None:
        floor = floor_height(x, up)
        floor_src = "lowest point reached"
    com = (m[None, :, None] * x).sum(1) / m.sum()  # [T, 3]
    ch = com @ up - floor  # centroid height above the floor [T]
    ext0 = x[0].max(0) - x[0].min(0)
    L = max(float(np.percentile(h[0], 99.5) - np.percentile(h[0], 0.5)), float(ext0.max()), 1e-6)
    t_unit = math.sqrt(L / g)  # [s]

    def vert_extent(i: int) -> float:
        lo, hi = np.percentile(h[i], [0.5, 99.5])
        return float(hi - lo)

    def horiz(i: int) -> np.ndarray:
        d = x[i] - com[i]
        return d - (d @ up)[:, None] * up[None, :]

    def radius(i: int) -> float:
        d = horiz(i)
        return float(np.sqrt((m * (d * d).sum(1)).sum() / m.sum()))

    # lowest particle above the floor per frame; a contact is within 3 % of L of it
    low = h.min(axis=1) - floor
    touching = np.nonzero(low < 0.03 * L)[0]
    # rebound: best rise after a low point AT GROUND LEVEL (within 0.1 L of the lowest
    # centroid height; frames are too coarse to catch the contact itself) over the fall
    # before it: a body that tumbles in the air raises its centroid without bouncing
    rebound = 0.0
    for k in range(1, T - 1):
        near = ch[k] <= ch.min() + 0.1 * L
        if near and ch[k] <= ch[k - 1] and ch[k] <= ch[k + 1]:
            fall = float(ch[: k + 1].max() - ch[k])
            rise = float(ch[k:].max() - ch[k])
            rebound = max(rebound, rise / max(fall, 0.2 * L))
    fall_distance = float(ch[0] - ch.min()) / L
    radii = np.array([radius(i) for i in range(T)])
    r0, r1 = radii[0], radii[-1]
    e0, e1 = vert_extent(0), vert_extent(T - 1)
    diam1 = 2.0 * float(np.percentile(np.linalg.norm(horiz(T - 1), axis=1), 97.5))
    # squash: per frame, undo the best rotation and compare the extents along the rest
    # pose's axes (1st-99th percentile), so a tumbling body is not read as squashed
    c0 = x[0] - (m[:, None] * x[0]).sum(0) / m.sum()
    ext_rest = np.maximum(np.percentile(c0, 99, axis=0) - np.percentile(c0, 1, axis=0), 1e-3 * L)
    residuals, tips, squash, strain, rot = [], [], [], [], 0.0
    for i in range(T):
        R, res, tip = _kabsch(x[0], x[i], m, tip=True)
        residuals.append(res / L)
        tips.append(tip / L)
        back = (x[i] - com[i]) @ R  # rotated back into the rest pose's frame
        ext_i = np.percentile(back, 99, axis=0) - np.percentile(back, 1, axis=0)
        # axes thinner than a fifth of L (a rod's cross-section) are not judged
        judged = ext_rest >= 0.2 * L
        squash.append(float(np.max(np.where(judged, 1.0 - ext_i / ext_rest, -1.0))))
        strain.append(np.where(judged, ext_i / ext_rest - 1.0, 0.0))
        if i == T - 1:
            rot = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))
    squash_arr = np.clip(np.array(squash), 0.0, 1.0)
    k_sq = int(np.argmax(squash_arr))
    peak_squash = float(squash_arr[k_sq])
    after = np.nonzero(squash_arr[k_sq:] <= 0.5 * peak_squash)[0]
    squash_recovery_s = float(t[k_sq + after[0]] - t[k_sq]) if after.size else None
    # bend: the largest relative rotation between slabs of the rest shape cut across its
    # long axis (6 slabs of equal particle count, best-fit rotation of each at the end);
    # a plastic hinge at a clamp shows as the end slab turned against the clamped one
    p0 = c0
    axis = np.linalg.svd(p0 * np.sqrt(m / m.sum())[:, None], full_matrices=False)[2][0]
    order = np.argsort(p0 @ axis)
    rots = []
    for part in np.array_split(order, 6):
        if part.size >= 4:
            rots.append(_kabsch(x[0][part], x[-1][part], m[part])[0])
    bend = 0.0
    for i in range(len(rots)):
        for j in range(i + 1, len(rots)):
            c = (np.trace(rots[i].T @ rots[j]) - 1.0) / 2.0
            bend = max(bend, math.degrees(math.acos(max(-1.0, min(1.0, c)))))
    # an elongated body (longest rest extent over twice the next) also swings as the
    # angle between its end slabs per frame: a rod's bending is mostly a rotation of its
    # parts, which the residuals above do not see
    sv = np.linalg.svd(p0 * np.sqrt(m / m.sum())[:, None], compute_uv=False)
    ends = np.array_split(order, 6)
    end_angle = None
    if len(sv) > 1 and sv[0] > 2.0 * sv[1] and ends[0].size >= 4 and ends[-1].size >= 4:
        # SIGNED: the relative rotation's vector (sin(angle) times its axis, [deg]) along
        # its direction of largest variance, so a bend up and a bend down differ
        vecs = []
        for i in range(T):
            ra = _kabsch(x[0][ends[0]], x[i][ends[0]], m[ends[0]])[0]
            rb = _kabsch(x[0][ends[-1]], x[i][ends[-1]], m[ends[-1]])[0]
            rr = ra.T @ rb
            vecs.append(
                0.5 * np.array([rr[2, 1] - rr[1, 2], rr[0, 2] - rr[2, 0], rr[1, 0] - rr[0, 1]])
            )
        vecs_a = np.degrees(np.array(vecs))  # [T, 3]
        direction = np.linalg.svd(vecs_a - vecs_a.mean(0), full_matrices=False)[2][0]
        end_angle = vecs_a @ direction
    max_change = float(max(residuals))
    # nothing visible to undo (under 2 % of L at its largest place) counts as recovered
    tip_max = float(max(tips))
    recovery = (
        (max_change - float(residuals[-1])) / max(max_change, 0.02) if tip_max >= 0.02 else 1.0
    )
    if "v" in traj:
        v = np.asarray(traj["v"], dtype=np.float64)[:, ::stride]
    else:
        v = np.gradient(x, t, axis=0) if T > 1 else np.zeros_like(x)
    speed = np.linalg.norm(v, axis=-1).mean(1) / math.sqrt(g * L)  # [T]
    tail = max(1, int(math.ceil(0.1 * T)))
    # contact: the first frame whose lowest point is within 3 % of L of the floor; the
    # pace is the mean speed after it (what happens on the ground, not the fall)
    contact = int(touching[0]) if touching.size else None
    first = 0 if contact is None else min(contact + 1, T - 1)
    pace = float(speed[first:].mean())
    # spread: how long the horizontal radius takes to make 80 % of its largest growth
    grow = radii - r0
    gmax = float(grow.max())
    spread_time_s = None
    if gmax > 0.05 * L:
        k80 = int(np.nonzero(grow >= 0.8 * gmax)[0][0])
        spread_time_s = float(t[k80] - t[contact if contact is not None else 0])
    extents = np.array([vert_extent(i) for i in range(T)])
    # rotation-invariant shape signals only: a tumbling body changes its vertical
    # extent without oscillating
    # the signed strain along the rest axis that changes most: a squash-and-stretch
    # wobble swings both ways about the rest shape (the squash above is one-sided)
    strain_arr = np.array(strain)  # [T, 3]
    along = strain_arr[:, int(np.argmax(strain_arr.std(0)))]
    trains = [_swing_train(np.array(signal), t, 0.01) for signal in (residuals, tips, along)]
    if end_angle is not None:  # in units of 100 deg, swings over 2 deg
        trains.append(_swing_train(np.array(end_angle) / 100.0, t, 0.02))
    names = ["shape", "shape", "strain", "end angle"][: len(trains)]
    best = max(range(len(trains)), key=lambda k: (trains[k]["swings"], trains[k]["amplitude"]))
    osc = trains[best]
    seen = [_swing_train(np.array(sig), t, VISIBLE_SWING) for sig in (residuals, tips, along)]
    if end_angle is not None:
        seen.append(_swing_train(np.array(end_angle) / 100.0, t, VISIBLE_SWING_ANGLE / 100.0))
    visible_swings = max(tr["swings"] for tr in seen)
    # in one piece: links shorter than 2.5x the rest spacing, at the last frame
    from scipy.spatial import cKDTree

    intact = 1.0
    if x.shape[1] >= 2:
        # the link length: the shortest multiple of the median spacing at which the rest
        # shape is one piece (a surface layer and an interior fill sampled at different
        # spacings are one body); the end is judged with the same links, relative to the start
        d0 = float(np.median(cKDTree(x[0]).query(x[0], k=2)[0][:, 1]))
        for f in (2.5, 4.0, 6.0, 10.0):
            start = _pieces(x[0], m, f * d0)
            if start >= 0.99:
                break
        intact = min(1.0, _pieces(x[-1], m, f * d0) / start)
    horiz_travel = com[-1] - com[0]
    horiz_travel = horiz_travel - (horiz_travel @ up) * up
    return {
        "size_L": L,
        "time_unit_s": t_unit,
        "floor": float(floor),
        "floor_source": floor_src,
        "fall_distance": fall_distance,
        "rebound": float(min(rebound, 2.0)),
        "spread": (r1 - r0) / L,
        "max_spread": gmax / L,
        "spread_time_s": spread_time_s,
        "aspect": e1 / max(diam1, 1e-9),
        "flatten": 1.0 - e1 / max(e0, 1e-9),
        "peak_squash": peak_squash,
        "final_squash": float(squash_arr[-1]),
        "peak_squash_time_s": float(t[k_sq] - t[0]),
        "squash_recovery_s": squash_recovery_s,
        "shape_change": float(residuals[-1]),
        "max_shape_change": max_change,
        "max_tip_change": float(max(tips)),
        "bend_deg": float(bend),
        "recovery": float(recovery),
        "reversals": float(_reversals(extents, 0.01 * L)),
        "osc_swings": osc["swings"],
        "osc_amplitude": osc["amplitude"],
        "osc_frequency_hz": osc["frequency_hz"],
        "osc_signal": names[best],
        "osc_visible_swings": float(visible_swings),
        "speed": float(speed.mean()),
        "pace": pace,
        "contact_time_s": None if contact is None else float(t[contact] - t[0]),
        "final_speed": float(speed[-tail:].mean()),
        "late_spread": float(radii[-1] - radii[max(0, T - 1 - max(1, T // 4))]) / L,
        "travel": float(np.linalg.norm(horiz_travel)) / L,
        "rotation_deg": rot,
        "max_displacement": float(np.linalg.norm(x - x[:1], axis=-1).max()) / L,
        "intact": intact,
    }


def _pct(v: float) -> str:
    return f"{100.0 * v:.0f} %"


_SAY: dict[str, Callable[[dict[str, Any]], str]] = {
    "fall_distance": lambda m: f"centroid fell {m['fall_distance']:.2g} L",
    "rebound": lambda m: f"rebound {_pct(m['rebound'])} of the fall",
    "spread": lambda m: (
        f"spread {m['spread']:+.2g} L"
        + (
            f" (80 % of its growth {m['spread_time_s']:.2f} s after contact)"
            if m.get("spread_time_s") is not None
            else ""
        )
    ),
    "aspect": lambda m: f"final height / width {m['aspect']:.2f}",
    "flatten": lambda m: f"final height lost {_pct(m['flatten'])}",
    "peak_squash": lambda m: (
        f"peak squash {_pct(m['peak_squash'])}"
        + (
            f", half undone in {m['squash_recovery_s']:.2f} s"
            if m.get("squash_recovery_s") is not None and m["peak_squash"] > 0.02
            else ""
        )
    ),
    "shape_change": lambda m: f"final shape change {_pct(m['shape_change'])} of L",
    "max_shape_change": lambda m: f"largest shape change {_pct(m['max_shape_change'])} of L",
    "max_tip_change": lambda m: (
        f"its most moved part left its shape by {_pct(m['max_tip_change'])} of L"
    ),
    "bend_deg": lambda m: f"bent {m['bend_deg']:.0f} deg",
    "recovery": lambda m: f"{_pct(max(0.0, m['recovery']))} of the shape change undone",
    "osc_swings": lambda m: (
        f"{m['osc_swings']:.0f} swings"
        + (
            f" of its end angle, {100 * m['osc_amplitude']:.0f} deg"
            if m.get("osc_signal") == "end angle"
            else f" of {_pct(m['osc_amplitude'])} of L"
        )
        + (f" at {m['osc_frequency_hz']:.2g} Hz" if m["osc_frequency_hz"] > 0 else "")
    ),
    "osc_visible_swings": lambda m: (
        f"{m['osc_visible_swings']:.0f} visible swings (over {_pct(VISIBLE_SWING)} of L)"
        + (
            f"; {m['osc_swings']:.0f} from 1 %"
            if m["osc_swings"] != m["osc_visible_swings"]
            else ""
        )
    ),
    "pace": lambda m: f"pace after contact {m['pace']:.2g} sqrt(gL)",
    "final_speed": lambda m: f"final speed {m['final_speed']:.2g} sqrt(gL)",
    "late_spread": lambda m: f"spread {m['late_spread']:+.2g} L in the last quarter",
    "travel": lambda m: f"travelled {m['travel']:.2g} L",
    "rotation_deg": lambda m: f"turned {m['rotation_deg']:.0f} deg",
    "max_displacement": lambda m: f"largest displacement {m['max_displacement']:.2g} L",
    "intact": lambda m: f"{_pct(m['intact'])} of the mass in one piece",
}


UNMENTIONED: dict[str, float] = {
    "bounce_seen": 0.25,
    "spread": 0.25,
    "oscillate": 0.25,
    "travel": 0.1,
    "rotate": 0.1,
}
"""Salient motions and their weights: when the prompt does not mention one (nor another
behaviour read from the same measurement), it is expected LOW, and its score raised to
this weight multiplies the prompt's score (a prompt names the striking motion it wants;
an unasked-for bounce, splash or wobble counts against the match, a roll or a turn a
little)."""
UNMENTIONED_MEASURE: dict[str, str] = {"oscillate": "osc_visible_swings"}
"""The measure an unmentioned motion is judged by where it differs from the asked one: an
unasked oscillation counts only with swings a person sees (:data:`VISIBLE_SWING`). A duck
asked to "jump right back up" that jiggled 4 times by 1 % of L after landing looked the same
as one that jiggled twice (side by side in 96 px videos), yet its score fell 0.90 -> 0.73
(BENCHMARKS.md, "The embedded motion prior"); a wobble the prompt asks for is still
measured from 1 % of L ("vibrates" is a small oscillation)."""
UNMENTIONED_MIN = 0.25
"""An unmentioned motion's term never goes below this (it is a hint, not a claim)."""
SCORE_FLOOR = 0.02
"""Each claim's score is floored here before the harmonic mean (one failed claim pulls
the score toward 0 without making it exactly 0)."""


def _logistic(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-max(-60.0, min(60.0, z))))


def behaviour_score(b: Behaviour, value: float) -> float:
    """How "high" ``value`` is for behaviour ``b`` (0..1; a band: inside it)."""
    s = _logistic((value - b.threshold) / b.width)
    if b.upper is not None:
        s *= 1.0 - _logistic((value - b.upper) / b.width)
    return s


def motion_adherence(
    prompt: str,
    traj: dict[str, np.ndarray] | None = None,
    *,
    measurements: dict[str, Any] | None = None,
    floor: float | None = None,
) -> dict[str, Any]:
    """Score ``prompt`` against a trajectory (or precomputed ``measurements``).

    Returns ``{"score", "score_mean", "prompt", "behaviours": [{name, expected,
    measured, threshold, score, weight, source, measure, doc, explain}], "explanations",
    "cues", "measurements"}``; ``score`` is None with a ``reason`` when the prompt holds
    no motion word this module knows. ``explanations``: one line per term the prompt
    asked for, e.g. ``"squashes: peak squash 26 % -> 0.99"``.
    """
    if measurements is None:
        if traj is None:
            raise ValueError("motion_adherence needs a trajectory or measurements")
        measurements = measure(traj, floor=floor)
    parsed = parse_prompt(prompt)
    rows = []
    expected = dict(parsed["expected"])
    mentioned = bool(expected)
    asked = {BEHAVIOURS[n].measure for n in expected}
    for name, w in UNMENTIONED.items():
        if name in parsed["tolerated"]:
            continue
        if mentioned and name not in expected and BEHAVIOURS[name].measure not in asked:
            expected[name] = (-1, w)
    for name, (sign, weight) in expected.items():
        b = BEHAVIOURS[name]
        from_prompt = name in parsed["expected"]
        key = b.measure if from_prompt else UNMENTIONED_MEASURE.get(name, b.measure)
        if key != b.measure:
            b = replace(b, measure=key)
        val = float(measurements[key])
        s = behaviour_score(b, val)
        s = s if sign > 0 else 1.0 - s
        if not from_prompt:
            s = UNMENTIONED_MIN + (1.0 - UNMENTIONED_MIN) * s
        said = _SAY[b.measure](measurements) if b.measure in _SAY else f"{b.measure} {val:.3g}"
        who = ", ".join(parsed["words"].get(name, [])) or f"not asked to {name}"
        rows.append(
            {
                "name": name,
                "expected": "high" if sign > 0 else "low",
                "measured": val,
                "threshold": b.threshold,
                "score": s,
                "weight": weight,
                "source": "prompt" if from_prompt else "not mentioned",
                "measure": b.measure,
                "doc": b.doc,
                "explain": f"{who}: {said} -> {s:.2f}",
            }
        )
    out: dict[str, Any] = {
        "prompt": prompt,
        "cues": parsed["cues"],
        "behaviours": rows,
        "measurements": measurements,
    }
    if not mentioned:
        out["behaviours"] = []
        out["score"] = None
        out["score_mean"] = None
        out["explanations"] = []
        out["reason"] = "no motion words recognised in the prompt (see metrics.adherence.CUES)"
    else:
        wsum = sum(r["weight"] for r in rows)
        asked = [r for r in rows if r["source"] == "prompt"]
        # the claims: a weighted harmonic mean, so one claim the motion contradicts
        # dominates (1, 1, 0.05 -> 0.14; the geometric mean would say 0.37)
        inv = sum(r["weight"] / max(r["score"], SCORE_FLOOR) for r in asked)
        claims = sum(r["weight"] for r in asked) / inv
        # an unasked-for motion multiplies (score ** weight): a hint that a striking motion
        # went unmentioned, not diluted by how many claims the prompt made
        hints = sum(r["weight"] * math.log(r["score"]) for r in rows if r not in asked)
        out["score"] = claims * math.exp(hints)
        out["score_mean"] = sum(r["weight"] * r["score"] for r in rows) / wsum
        out["explanations"] = [r["explain"] for r in rows if r["source"] == "prompt"]
    return out
