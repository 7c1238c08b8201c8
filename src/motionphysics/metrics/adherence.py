"""Motion adherence: does the simulated motion do what the prompt's motion words say?

The paper names the lack of a prompt-adherence metric that sees temporal dynamics as
future work (CLIPSIM scores frames one at a time; OC sees 8 frames of appearance).
This score needs no model weights: it reads the prompt's motion words and checks the
behaviours they imply against measurements of the trajectory alone.

1. **Cues** (:data:`CUES`): word patterns (stems, so "bounce", "bounces", "bouncing",
   "bouncy" all match) for motions (bounce / rebound, splash / spread / flow, keep
   shape / rigid, wobble / jiggle, squash / flatten, stay / permanent, collapse,
   heap / pile, ooze / slowly, fall / drop, bend, roll / slide, spin, rest) and, with
   half weight, for materials that imply a motion (rubber -> rebound, water -> spread,
   sand -> heap, clay -> stays deformed, honey -> slow ...). A negation up to three
   words before a cue ("does not bounce", "without spreading") flips it.
2. **Behaviours** (:data:`BEHAVIOURS`): each cue expects some behaviours to be high or
   low, with a weight (1 for what the words say, 0.5 for what they imply). Cues that
   agree add up (weight capped at 1); cues that disagree cancel.
3. **Measurements** (:func:`measure`), dimensionless so they transfer across scene
   sizes: L is the object's largest initial extent, h the height above the floor,
   c the mass centroid (all from ``trajectory.npz``: ``x [T, P, 3]`` m, ``t [T]`` s,
   optional ``mass [P]`` kg and ``gravity [3]`` m/s^2).
4. **Score** of one behaviour: a logistic ramp ``1 / (1 + exp(-(m - threshold) / width))``
   for "high" (one minus it for "low"), so 0.5 at the threshold; the prompt's score is
   the weighted mean. Each behaviour is reported with its expected direction, measured
   value, threshold and score.

The thresholds are physical judgements, documented beside each behaviour (e.g. a
bounce is a centroid rise of at least 15 % of the fall); they are not fitted to the
project's example scenes. This module must not read files or run simulations.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["BEHAVIOURS", "CUES", "parse_prompt", "measure", "motion_adherence", "floor_height"]


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
            "rise of the centroid after a low point over the fall before it (fall floored at 0.2 L)",
        ),
        Behaviour(
            "spread",
            "spread",
            0.2,
            0.07,
            "growth of the RMS horizontal radius about the centroid, final minus initial, in L",
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
            " max(max, 0.02)",
        ),
        Behaviour(
            "flatten",
            "flatten",
            0.25,
            0.08,
            "loss of vertical extent: 1 - final / initial extent along up",
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
            "max_shape_change",
            0.06,
            0.02,
            "largest shape change over the clip (RMS Procrustes residual / L)",
        ),
        Behaviour(
            "oscillate",
            "reversals",
            2.5,
            0.75,
            "reversals of the vertical extent by more than 1 % of L (wobble, jiggle)",
        ),
        Behaviour(
            "fast",
            "speed",
            0.5,
            0.15,
            "mean particle speed over the clip / sqrt(g L) (LOW: oozing, slow)",
        ),
        Behaviour(
            "moving_at_end",
            "final_speed",
            0.15,
            0.05,
            "mean particle speed in the last 10 % of frames / sqrt(g L) (LOW: settled)",
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
    )
}

# A cue: regex over the lower-cased prompt (word stems; \b-anchored) -> [(behaviour, +1 high
# / -1 low, weight)]. Motion words weigh 1, what they imply 0.5; material words 0.5.
_H, _L = +1, -1
CUES: list[tuple[str, str, list[tuple[str, int, float]]]] = [
    # -- motions
    (
        "bounce",
        r"bounc\w*|rebound\w*|spring\w* back|jump\w* back|bounds? back|recoil\w*",
        [("rebound", _H, 1.0), ("spread", _L, 0.5)],
    ),
    (
        "splash",
        r"splash\w*|splatter\w*|spatter\w*|burst\w*",
        [("spread", _H, 1.0), ("heap", _L, 0.5), ("rebound", _L, 0.5)],
    ),
    (
        "spread",
        r"spread\w*|spill\w*|scatter\w*|puddle\w*|sheet\w*|fans? out|splay\w*",
        [("spread", _H, 1.0), ("heap", _L, 0.5)],
    ),
    (
        "flow",
        r"flow\w*|pour\w*|stream\w*|slosh\w*|runs? (?:out|across|over|down)|gush\w*|drain\w*",
        [("spread", _H, 1.0), ("deform", _H, 0.5), ("flatten", _H, 0.5)],
    ),
    (
        "rigid",
        r"rigid\w*|keeps? (?:its|their|the) (?:original )?shape|holds? (?:its|their) shape"
        r"|retains? (?:its|their) shape|maintains? (?:its|their) shape|unchang\w*|undeform\w*"
        r"|without deform\w*|stiff\w*|solid\w*|unbreakable|does ?n[o']t deform",
        [("deform_any", _L, 1.0), ("spread", _L, 0.5)],
    ),
    (
        "wobble",
        r"wobbl\w*|jiggl\w*|wiggl\w*|vibrat\w*|oscillat\w*|quiver\w*|jelly-like|sway\w*|shak\w*"
        r"|springy|bobs?|bobbing",
        [("oscillate", _H, 1.0), ("deform", _L, 0.5)],
    ),
    (
        "squash",
        r"squash\w*|flatten\w*|(?:pressed|pushed|squeezed|crushed) flat|crush\w*|compress\w*"
        r"|smash\w*|pancake\w*|dent\w*|squish\w*|flat\b",
        [("flatten", _H, 1.0), ("deform", _H, 0.5), ("spread", _L, 1.0), ("tall", _L, 0.5)],
    ),
    (
        "stay",
        r"permanent\w*|stays? (?:bent|flat|deformed|squashed|dented|that way|down)"
        r"|keeps? (?:its|their|the) (?:new|deformed|flattened|squashed|bent|dented) (?:shape|form)"
        r"|holds? (?:its|their|the) new shape|remains? (?:bent|flat|deformed|dented)|plastically"
        r"|does ?n[o']t (?:spring|bounce|recover) back|never recovers",
        [("recovery", _L, 1.0), ("rebound", _L, 0.5), ("moving_at_end", _L, 0.5)],
    ),
    (
        "recover",
        r"recover\w*|returns? to (?:its|their) (?:original )?shape|springs? back|bounces? back"
        r"|regains? (?:its|their) shape|restor\w*",
        [("recovery", _H, 1.0)],
    ),
    (
        "bend",
        r"bend\w*|bent|buckl\w*|curl\w*|fold\w*|twist\w*|warp\w*|kink\w*|sag\w*|droop\w*",
        [("bend", _H, 1.0), ("spread", _L, 0.5)],
    ),
    (
        "collapse",
        r"collaps\w*|crumbl\w*|slump\w*|caves? in|topple\w*|disintegrat\w*|falls? apart"
        r"|gives? way|subsid\w*",
        [("collapse", _H, 1.0), ("spread", _H, 0.5), ("moving_at_end", _L, 0.5)],
    ),
    (
        "heap",
        r"heap\w*|piles? up|pil(?:e|es|ed|ing)\b|mound\w*|cone\b|stack\w* up|build\w* up",
        [("heap", _H, 1.0), ("flatten", _H, 0.5), ("moving_at_end", _L, 0.5)],
    ),
    (
        "slow",
        r"slow\w*|ooz\w*|creep\w*|gradual\w*|gentl\w*|sluggish\w*|viscous\w*|thick\w*|languid\w*"
        r"|lazil\w*|drip\w*|trickl\w*",
        [("fast", _L, 1.0)],
    ),
    (
        "fast",
        r"quick\w*|rapid\w*|fast\b|violent\w*|explosive\w*|sudden\w*|hurl\w*|shoots?\b",
        [("fast", _H, 1.0)],
    ),
    (
        "fall",
        r"fall\w*|fell\b|drop\w*|dropped|tumbl\w*|plummet\w*|plung\w*|descend\w*|lands? on"
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
        r"rubber\w*|elastic\w*|bouncy|trampoline|balloon\w*",
        [("rebound", _H, 0.5)],
    ),
    (
        "liquid material",
        r"water\w*|liquid\w*|fluid\w*|juice|milk|wine|coffee|oil\b|rain\w*|droplet\w*",
        [("spread", _H, 0.5), ("heap", _L, 0.5)],
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
        "paste material",
        r"toothpaste|paste\b|cream\w*|mud\w*|honey|syrup|ketchup|mayonnaise|slime|lava|cement|batter",
        [("heap", _H, 0.5), ("spread", _L, 0.5)],
    ),
]
_COMPILED = [(name, re.compile(rf"\b(?:{pat})"), eff) for name, pat, eff in CUES]
_NEGATORS = {"not", "no", "never", "without", "nor", "cannot", "neither", "hardly", "barely"}
_NEG_SUFFIX = ("n't", "n’t")


def _negated(text: str, start: int) -> bool:
    before = re.findall(r"[\w'’]+", text[:start])[-3:]
    return any(w in _NEGATORS or w.endswith(_NEG_SUFFIX) or w in ("dont", "doesnt") for w in before)


def parse_prompt(prompt: str) -> dict[str, Any]:
    """The cues found in ``prompt`` and the behaviours they expect.

    Returns ``{"cues": [{"cue", "words", "negated"}], "expected": {behaviour: (sign, weight)}}``
    where sign is +1 (high) or -1 (low) and weight in (0, 1]. "does not bounce back"
    matches both "bounce" and "recover" (both negated), as it should.
    """
    text = " ".join(str(prompt).lower().replace("’", "'").split())
    found: list[dict[str, Any]] = []
    acc: dict[str, float] = {}
    taken: list[tuple[int, int]] = []
    for name, rx, effects in _COMPILED:
        for m in rx.finditer(text):
            neg = _negated(text, m.start())
            found.append({"cue": name, "words": m.group(0), "negated": neg})
            taken.append(m.span())
            for beh, sign, w in effects:
                # a negated motion says "not this", not "the opposite": its implications
                # (half weight) are dropped, the main behaviour is flipped
                if neg and w < 1.0:
                    continue
                acc[beh] = acc.get(beh, 0.0) + (-sign if neg else sign) * w
            break  # one match per cue is enough: repeating a word does not weigh more
    expected = {b: (1 if v > 0 else -1, min(1.0, abs(v))) for b, v in acc.items() if abs(v) > 1e-9}
    return {"cues": found, "expected": expected}


# ----------------------------------------------------------------------------------- measurements
def floor_height(x: np.ndarray, up: np.ndarray) -> float:
    """Floor height along ``up`` when no collider is known: the lowest point any particle
    reaches over the clip (0.1th percentile per frame, minimum over frames) [m]."""
    h = np.asarray(x, dtype=np.float64) @ up
    return float(np.percentile(h, 0.1, axis=1).min())


def _kabsch(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Best rotation R mapping centred p onto centred q (weights w); returns (R, rms residual)."""
    pc = p - (w[:, None] * p).sum(0) / w.sum()
    qc = q - (w[:, None] * q).sum(0) / w.sum()
    H = (w[:, None] * pc).T @ qc
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    r = qc - pc @ R.T
    return R, float(np.sqrt((w * (r * r).sum(1)).sum() / w.sum()))


def _reversals(signal: np.ndarray, hysteresis: float) -> int:
    """Number of direction reversals of ``signal`` larger than ``hysteresis``."""
    n, direction, ext = 0, 0, float(signal[0])
    for v in signal[1:]:
        v = float(v)
        if direction >= 0:
            if v > ext:
                ext = v
            elif ext - v > hysteresis:
                n += direction > 0
                direction, ext = -1, v
        if direction < 0:
            if v < ext:
                ext = v
            elif v - ext > hysteresis:
                n += 1
                direction, ext = 1, v
    return n


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

    def vert_extent(i: int) -> float:
        lo, hi = np.percentile(h[i], [0.5, 99.5])
        return float(hi - lo)

    def horiz(i: int) -> np.ndarray:
        d = x[i] - com[i]
        return d - (d @ up)[:, None] * up[None, :]

    def radius(i: int) -> float:
        d = horiz(i)
        return float(np.sqrt((m * (d * d).sum(1)).sum() / m.sum()))

    # rebound: best rise after a low point over the fall before it
    rebound = 0.0
    for k in range(1, T - 1):
        if ch[k] <= ch[k - 1] and ch[k] <= ch[k + 1]:
            fall = float(ch[: k + 1].max() - ch[k])
            rise = float(ch[k:].max() - ch[k])
            rebound = max(rebound, rise / max(fall, 0.2 * L))
    fall_distance = float(ch[0] - ch.min()) / L
    r0, r1 = radius(0), radius(T - 1)
    e0, e1 = vert_extent(0), vert_extent(T - 1)
    diam1 = 2.0 * float(np.percentile(np.linalg.norm(horiz(T - 1), axis=1), 97.5))
    residuals, rot = [], 0.0
    for i in range(T):
        R, res = _kabsch(x[0], x[i], m)
        residuals.append(res / L)
        if i == T - 1:
            rot = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))
    # bend: the largest relative rotation between slabs of the rest shape cut across its
    # long axis (6 slabs of equal particle count, best-fit rotation of each at the end);
    # a plastic hinge at a clamp shows as the end slab turned against the clamped one
    p0 = x[0] - (m[:, None] * x[0]).sum(0) / m.sum()
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
    max_change = float(max(residuals))
    recovery = (max_change - float(residuals[-1])) / max(max_change, 0.02)
    if "v" in traj:
        v = np.asarray(traj["v"], dtype=np.float64)[:, ::stride]
    else:
        v = np.gradient(x, t, axis=0) if T > 1 else np.zeros_like(x)
    speed = np.linalg.norm(v, axis=-1).mean(1) / math.sqrt(g * L)  # [T]
    tail = max(1, int(math.ceil(0.1 * T)))
    extents = np.array([vert_extent(i) for i in range(T)])
    horiz_travel = com[-1] - com[0]
    horiz_travel = horiz_travel - (horiz_travel @ up) * up
    return {
        "size_L": L,
        "floor": float(floor),
        "floor_source": floor_src,
        "fall_distance": fall_distance,
        "rebound": float(min(rebound, 2.0)),
        "spread": (r1 - r0) / L,
        "aspect": e1 / max(diam1, 1e-9),
        "flatten": 1.0 - e1 / max(e0, 1e-9),
        "shape_change": float(residuals[-1]),
        "max_shape_change": max_change,
        "bend_deg": float(bend),
        "recovery": float(recovery),
        "reversals": float(_reversals(extents, 0.01 * L)),
        "speed": float(speed.mean()),
        "final_speed": float(speed[-tail:].mean()),
        "travel": float(np.linalg.norm(horiz_travel)) / L,
        "rotation_deg": rot,
        "max_displacement": float(np.linalg.norm(x - x[:1], axis=-1).max()) / L,
    }


UNMENTIONED = ("fall", "rebound", "spread", "travel", "rotate", "oscillate")
"""Salient motions: when the prompt does not mention one, it is expected LOW at weight
UNMENTIONED_WEIGHT (a prompt names the striking motion it wants; an unasked-for bounce,
splash or fall counts a little against the match)."""
UNMENTIONED_WEIGHT = 0.25


def _logistic(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-max(-60.0, min(60.0, z))))


def motion_adherence(
    prompt: str,
    traj: dict[str, np.ndarray] | None = None,
    *,
    measurements: dict[str, Any] | None = None,
    floor: float | None = None,
) -> dict[str, Any]:
    """Score ``prompt`` against a trajectory (or precomputed ``measurements``).

    Returns ``{"score", "prompt", "behaviours": [{name, expected, measured, threshold,
    score, weight, measure, doc}], "cues", "measurements"}``; ``score`` is None with a
    ``reason`` when the prompt holds no motion word this module knows.
    """
    if measurements is None:
        if traj is None:
            raise ValueError("motion_adherence needs a trajectory or measurements")
        measurements = measure(traj, floor=floor)
    parsed = parse_prompt(prompt)
    rows = []
    expected = dict(parsed["expected"])
    mentioned = bool(expected)
    for name in UNMENTIONED:
        if mentioned and name not in expected:
            expected[name] = (-1, UNMENTIONED_WEIGHT)
    for name, (sign, weight) in expected.items():
        b = BEHAVIOURS[name]
        val = float(measurements[b.measure])
        s = _logistic((val - b.threshold) / b.width)
        rows.append(
            {
                "name": name,
                "expected": "high" if sign > 0 else "low",
                "measured": val,
                "threshold": b.threshold,
                "score": s if sign > 0 else 1.0 - s,
                "weight": weight,
                "source": "prompt" if name in parsed["expected"] else "not mentioned",
                "measure": b.measure,
                "doc": b.doc,
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
        out["reason"] = "no motion words recognised in the prompt (see metrics.adherence.CUES)"
    else:
        wsum = sum(r["weight"] for r in rows)
        out["score"] = sum(r["weight"] * r["score"] for r in rows) / wsum
    return out
