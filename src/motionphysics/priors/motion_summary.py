"""What a refinement did to the motion, in the motion prior's words.

:func:`motion_record` reads the motion group the prompt asks for
(:func:`~motionphysics.language.captions.prompt_motion_group`) and the motion group of the
simulated trajectory before and after refinement (the caption rules of
:func:`~motionphysics.language.captions.motion_group` on the measures of
:func:`~motionphysics.priors.motion_data.clip_measures`: rebound, peak and final shape
change, spread, wobble, late speed), so the summary and the report can put the motion
asked for next to the motion simulated. :func:`motion_lines` writes it for the summary.

A group is ``None`` when the motion fits no group with a margin (the captions never
claim a motion then); the measures are given either way.

Beside the groups, each trajectory gets the motion adherence score that ``motionphysics
eval`` computes (:func:`~motionphysics.metrics.adherence.motion_adherence`, the prompt
against the measured motion, 0..1): the same number ``metrics.json`` holds for the refined
run, and the number the initial estimate would have had.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "adherence_of",
    "motion_lines",
    "motion_record",
    "asked_motion",
    "plain_motion_lines",
    "plain_motion_record",
    "trajectory_motion",
]

_SHOWN = ("rebound", "max_deform", "deform", "max_spread", "wobble")
MAX_PARTICLES = 4096
"""Particles the measures read (a seeded subset of a larger scene: the measures are
means over particles)."""


NEAR_ADHERENCE = 0.6
"""A run whose motion is not in the asked group by the caption rules is still called close
to what was asked when eval's motion adherence is at least this. Examples:
- a lump of clay that ended at 0.43 of its height, spread x1.6 and still creeping reads as
  "oozes" to the rules but scores 0.67 on "squashes flat": close;
- a rubber ball with a rebound of 0.23 scores 0.74 on "bounces back": close;
- the demo's bird (rebound 0.33 from its first impact, between the caption rules'
  groups) scores 0.54 on "bounces back": "partly as asked", no claim either way;
- a foam block that bounced and kept its shape scores 0.03 on "squashes flat"."""


STILL = 0.03
"""A run whose particles moved at most this fraction of the object's size (the largest
particle displacement over its largest side) hardly moved: its summary says so instead of
proposing a refinement (a rubber duck resting on its floor moved 0.5 %)."""


def _words(group: str | None) -> str:
    return "no motion group" if group is None else group.replace("_", " ")


def trajectory_motion(x, v, t, cls: str) -> dict[str, Any]:
    """``{"group", "measures"}`` of a trajectory ``x``/``v`` [T, P, 3] at times ``t`` [T]
    of a material class ``cls`` (``sand`` reads a collapse as "crumbles")."""
    from motionphysics.priors.motion_data import clip_measures, group_of

    x = np.asarray(x, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    if x.shape[1] > MAX_PARTICLES:
        idx = np.sort(np.random.default_rng(0).choice(x.shape[1], MAX_PARTICLES, replace=False))
        x, v = x[:, idx], v[:, idx]
    m = clip_measures(x, v, np.asarray(t, dtype=np.float64))
    measures = {k: float(m[k]) for k in _SHOWN}
    size = max(float(np.ptp(x[0], axis=0).max()), 1e-9)
    measures["moved"] = float(np.linalg.norm(x - x[:1], axis=-1).max()) / size
    return {"group": group_of(m, cls), "measures": measures}


def adherence_of(prompt: str, x, v, t, *, mass=None, gravity=None, floor=None) -> dict:
    """``{"score", "explanations"}``: eval's motion adherence of ``prompt`` on a trajectory
    ``x``/``v`` [T, P, 3] at times ``t``; ``score`` is None (with ``reason``) when the
    prompt holds no motion word the adherence knows."""
    from motionphysics.metrics.adherence import motion_adherence

    traj: dict[str, Any] = {"x": np.asarray(x), "v": np.asarray(v), "t": np.asarray(t)}
    if mass is not None:
        traj["mass"] = np.asarray(mass, dtype=np.float64)
    if gravity is not None:
        traj["gravity"] = np.asarray(gravity, dtype=np.float64)
    a = motion_adherence(prompt, traj, floor=floor)
    out = {"score": a.get("score"), "explanations": list(a.get("explanations") or [])}
    if a.get("score") is None and a.get("reason"):
        out["reason"] = a["reason"]
    return out


def motion_record(
    prompt: str,
    cls: str,
    t,
    before: tuple,
    after: tuple,
    *,
    mass=None,
    gravity=None,
    floor: float | None = None,
) -> dict[str, Any]:
    """The motion asked for and simulated: ``before``/``after`` are ``(x, v)`` of the
    initial and the refined trajectory at times ``t``. ``mass`` [P], ``gravity`` [3] and
    ``floor`` (ground height along up, or None: the lowest point reached) are what eval
    scores the adherence with. The motion asked is read for what ``cls`` can show
    (:func:`asked_motion`), as a run without refinement reads it."""
    asked, similarity = asked_motion(prompt, cls)
    rec: dict[str, Any] = {
        "asked": asked,
        "asked_similarity": float(similarity),
        "asked_words": motion_words(prompt) if asked is None else None,
        "before": trajectory_motion(*before, t, cls),
        "after": trajectory_motion(*after, t, cls),
    }
    for key, (x, v) in (("before", before), ("after", after)):
        rec[key]["adherence"] = adherence_of(
            prompt, x, v, t, mass=mass, gravity=gravity, floor=floor
        )
    return rec


def _said(r: dict[str, Any]) -> str:
    m = r["measures"]
    return (
        f"{_words(r['group'])} (rebound {m['rebound']:.2f}, peak shape change "
        f"{100 * m['max_deform']:.1f} %, spread x{m['max_spread']:.2f})"
    )


SECOND_READING_SIMILARITY = 0.6
"""How close a prompt's clause must be to a motion group's phrasings for the reading
without a group the material cannot show to count (:func:`asked_motion`)."""


def asked_motion(prompt: str, cls: str) -> tuple[str | None, float]:
    """The motion group ``prompt`` asks for, read for what material class ``cls`` can show,
    and its similarity. "crumbles" is the granular word for a collapse: a material that is
    not sand cannot show it (``captions.motion_group``), so its prompt is read without it
    ("a block of water collapses and splashes" asks for a splash, 0.76); a weak second
    reading is no reading ("toothpaste ... piles up" is nearest "bounces high" at 0.50)."""
    from motionphysics.language.captions import prompt_motion_group

    asked, similarity = prompt_motion_group(prompt)
    exclude: tuple[str, ...] = ()
    if asked == "crumbles" and cls != "sand":
        exclude = ("crumbles",)
        asked, similarity = prompt_motion_group(prompt, exclude=exclude)
        if similarity < SECOND_READING_SIMILARITY:
            asked = None
    if asked is not None and _unlike_its_group(prompt, asked, exclude):
        asked = None
    return asked, similarity


NEUTRAL_CUES = frozenset({"fall", "fast", "slow", "gentle"})
"""eval's cues that go with any motion group (how, not what): they neither confirm nor
refute a reading."""


def _group_cues() -> dict[str, frozenset[str]]:
    """Per motion group, eval's motion cues its own phrasings (training and held-out)
    contain: what a prompt of that group says in eval's words."""
    global _GROUP_CUES
    if _GROUP_CUES is None:
        from motionphysics.language import captions
        from motionphysics.metrics.adherence import parse_prompt

        held = getattr(captions, "HELD_OUT", {})
        _GROUP_CUES = {
            g: frozenset(
                c["cue"]
                for p in (*captions.TRAIN[g], *held.get(g, ()))
                for c in parse_prompt("a ball " + p)["cues"]
                if "material" not in c["cue"]
            )
            for g in captions.GROUPS
        }
    return _GROUP_CUES


_GROUP_CUES: dict[str, frozenset[str]] | None = None


def motion_words(prompt: str) -> list[str]:
    """The prompt's motion words as eval reads them (its cues, not negated, without the
    neutral ones and the material words)."""
    from motionphysics.metrics.adherence import parse_prompt

    return [
        str(c["words"])
        for c in parse_prompt(prompt)["cues"]
        if "material" not in c["cue"] and c["cue"] not in NEUTRAL_CUES
    ]


def _unlike_its_group(prompt: str, group: str, exclude: tuple[str, ...] = ()) -> bool:
    """Whether the prompt's deciding clause says, in eval's words, a motion none of
    ``group``'s phrasings says: "a copper rod falls and bends when it hits the floor" is
    nearest "squashes flat" by its sentence embedding (0.72), but "bends" is no word of a
    squash. A clause without such words keeps the reading."""
    from motionphysics.language.captions import prompt_motion_reading
    from motionphysics.metrics.adherence import parse_prompt

    _, _, clause = prompt_motion_reading(prompt, exclude=exclude)
    cues = {
        c["cue"]
        for c in parse_prompt(clause or "")["cues"]
        if "material" not in c["cue"] and c["cue"] not in NEUTRAL_CUES and not c["negated"]
    }
    return bool(cues) and not (cues & _group_cues()[group])


def plain_motion_record(
    prompt: str, cls: str, t, x, v, *, mass=None, gravity=None, floor: float | None = None
) -> dict[str, Any] | None:
    """The motion asked for (:func:`asked_motion`) and the motion of the trajectory
    ``x``/``v`` at times ``t`` of a run without refinement, with eval's adherence and the
    summary lines (:func:`plain_motion_lines`); None when the prompt asks for no motion."""
    asked, similarity = asked_motion(prompt, cls)
    words = motion_words(prompt)
    if asked is None and not words:
        return None
    rec: dict[str, Any] = {
        "asked": asked,
        "asked_similarity": float(similarity),
        "simulated": trajectory_motion(x, v, t, cls),
    }
    if asked is None:
        rec["asked_words"] = words  # a motion no group holds ("bends", "rolls"): eval's words
    rec["simulated"]["adherence"] = adherence_of(
        prompt, x, v, t, mass=mass, gravity=gravity, floor=floor
    )
    return {**rec, "lines": plain_motion_lines(rec)}


def plain_motion_lines(rec: dict[str, Any]) -> list[str]:
    """Summary lines of a run without refinement: the motion asked for and the motion
    simulated from the estimate; when they differ, what moves it toward the words."""
    asked, sim = rec["asked"], rec["simulated"]
    score = (sim.get("adherence") or {}).get("score")
    near = score is not None and score >= NEAR_ADHERENCE
    if asked is None:
        # a motion no group holds: eval's adherence to the words is all there is to say
        ok, verdict = near, "close to what was asked" if near else "not as asked"
        said = ", ".join(f"'{w}'" for w in rec.get("asked_words") or [])
        lines = [
            f"motion asked: {said} (no motion group of the motion prior holds it; eval "
            "reads the words)",
            f"  simulated: {_said(sim)} ({verdict})",
        ]
        if score is not None:
            lines.append(f"  motion adherence (eval, 0..1): {score:.2f}")
        return lines + _advice(ok, sim)
    if sim["group"] == asked:
        ok, verdict = True, "as asked"
    elif near:
        # the caption rules read it otherwise (or between groups), eval's adherence to
        # the prompt's own words says it is close: what the prompt's reader sees
        ok, verdict = True, "close to what was asked"
    elif sim["group"] is None:
        # between two groups (a rebound of 0.33 is neither a high bounce nor a small one
        # by the caption rules) and eval's adherence is not high: no claim either way
        ok, verdict = True, "partly as asked: between motion groups"
    else:
        ok, verdict = False, "not as asked"
    lines = [
        f"motion asked: {_words(asked)} (the prompt's motion words)",
        f"  simulated: {_said(sim)} ({verdict})",
    ]
    if score is not None:
        lines.append(f"  motion adherence (eval, 0..1): {score:.2f}")
    return lines + _advice(ok, sim)


def _advice(ok: bool, sim: dict[str, Any]) -> list[str]:
    """What moves a run that is not as asked toward the words (nothing when it is)."""
    moved = sim["measures"].get("moved")
    if not ok and moved is not None and moved < STILL:
        # no material makes a body at rest on its ground do anything: refining cannot help
        return [
            f"  it hardly moved (at most {100 * moved:.1f} % of its size): nothing sets it in "
            "motion (it starts on its ground, with no velocity or force); lift it with "
            "`scene.translate`, or give `sim.initial_velocity` or a force"
        ]
    if not ok:
        return [
            "  the estimate's values do not give that motion here: refine toward the words "
            "with `--prior motion --loss lmd` (the embedded prior), or set the `material:` "
            "values yourself"
        ]
    return []


def motion_lines(rec: dict[str, Any]) -> list[str]:
    """Summary lines: the motion asked for, and the motion before and after refinement."""

    asked = rec.get("asked")
    words = ", ".join(f"'{w}'" for w in rec.get("asked_words") or [])
    ask = (
        f"{_words(asked)} (the prompt's motion words)"
        if asked is not None
        else f"{words} (no motion group of the motion prior holds it; eval reads the words)"
        if words
        else "no motion group the motion prior knows (the prompt names none)"
    )
    lines = [f"motion asked: {ask}"]
    lines.append(f"  before refinement: {_said(rec['before'])}")
    mark = ""
    if asked is not None:
        b, a = rec["before"]["group"] == asked, rec["after"]["group"] == asked
        mark = " (as asked)" if a else (" (was as asked before)" if b else " (not as asked)")
    lines.append(f"  after refinement:  {_said(rec['after'])}{mark}")
    a0 = (rec["before"].get("adherence") or {}).get("score")
    a1 = (rec["after"].get("adherence") or {}).get("score")
    if a0 is not None and a1 is not None:
        trend = "rose" if a1 > a0 + 0.005 else ("fell" if a1 < a0 - 0.005 else "held")
        lines.append(f"  motion adherence (eval, 0..1): {a0:.2f} before, {a1:.2f} after ({trend})")
    return lines
