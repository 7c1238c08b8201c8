"""Labelled trajectories for :mod:`.adherence`, and the confusion matrices that check it.

Two kinds of labels, neither fitted by the score:

- :func:`hand_made`: one trajectory per motion word, built by hand so that it shows the
  word and nothing else (a ball that bounces high, one that barely bounces, a jelly
  that wobbles, a drop that splashes, honey that oozes, a block that keeps its shape, a
  block that crumbles into pieces, clay squashed flat, a rubber ball that squashes at
  impact and springs back, a clamped bar that bends for good, a clamped rod that
  vibrates gently, a sand column that collapses into a heap, a ball that rolls), each
  with the prompt (:data:`WORDS`) that says it;
- :func:`clip_confusion`: the motion prior's simulated clips (``motionphysics prior
  data``; each clip's group is its MEASURED motion, :func:`motionphysics.language.captions
  .motion_group`) scored against the group phrasings of :mod:`motionphysics.language.captions`.

:func:`confusion` scores every prompt on every labelled trajectory (rows: prompts, that
is words or groups; columns: the behaviours), :func:`margins` says by how much the
diagonal is the highest in every row and column. ``python -m
motionphysics.evaluation.adherence_calibration [--clips DIR]`` prints both as markdown
(BENCHMARKS.md, "Motion adherence: words x behaviours").

This module writes nothing; only :func:`clip_confusion` reads files (the clips).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from motionphysics.metrics.adherence import measure, motion_adherence

__all__ = ["WORDS", "clip_confusion", "confusion", "hand_made", "margins", "markdown"]

T, DT = 25, 0.04
"""Frames and frame spacing [s] of every hand-made trajectory (1 s at 25 fps)."""
G = 9.8
R = 0.15
"""Radius [m] of the hand-made balls (size L = 0.3 m)."""


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([27, seed])


def _ball(seed: int, n: int = 500, r: float = R) -> np.ndarray:
    """[n, 3] points filling a ball of radius ``r`` about the origin."""
    p = _rng(seed).normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p * r * _rng(seed + 100).random((n, 1)) ** (1 / 3)


def _box(seed: int, size: Sequence[float], n: int = 500) -> np.ndarray:
    """[n, 3] points filling a box of ``size`` centred on the origin."""
    return (_rng(seed).random((n, 3)) - 0.5) * np.asarray(size)


def _traj(frames: list[np.ndarray]) -> dict[str, np.ndarray]:
    return {
        "x": np.stack(frames),
        "t": np.arange(len(frames)) * DT,
        "gravity": np.array([0, 0, -G]),
    }


def _squashed(p: np.ndarray, s: float) -> np.ndarray:
    """``p`` compressed by ``s`` along z and bulged sideways at constant volume, about its base."""
    side = 1.0 / math.sqrt(max(1.0 - s, 1e-3))
    q = p * [side, side, 1.0 - s]
    return q - [0.0, 0.0, q[:, 2].min() - p[:, 2].min()]


def _bouncing_ball(seed: int, drop: float, rebound: float, squash: float) -> dict[str, np.ndarray]:
    """A ball released with its bottom ``drop`` m above the floor: it falls, squashes by
    ``squash`` at the impact frame and rises ``rebound`` of the drop, then falls again."""
    p = _ball(seed)
    v0 = math.sqrt(2 * G * drop)
    t_hit = v0 / G
    v1 = math.sqrt(rebound) * v0
    out = []
    for i in range(T):
        t = i * DT
        if t < t_hit:
            z = drop - 0.5 * G * t * t
        else:
            tau = (t - t_hit) % max(2 * v1 / G, 1e-9)
            z = max(0.0, v1 * tau - 0.5 * G * tau * tau)
        s = squash if abs(t - t_hit) < 0.6 * DT else 0.0
        q = _squashed(p, s)
        out.append(q + [0.0, 0.0, z + R])
    return _traj(out)


def _bounces_high():
    return _bouncing_ball(1, 0.6, 0.7, 0.03)


def _barely_bounces():
    return _bouncing_ball(2, 0.6, 0.12, 0.02)


def _squash_recover():
    """The rubber ball of issue 27: 26 % squash at impact, then back up 40 % of its drop."""
    return _bouncing_ball(3, 0.45, 0.4, 0.26)


def _wobbles():
    """A jelly cube dropped 20 cm: 20 % squash at impact, then a shape swing at 5 Hz
    that halves every 0.2 s about its rest shape."""
    p = _box(4, (0.3, 0.3, 0.3)) + [0, 0, 0.15]
    t_hit = math.sqrt(2 * 0.2 / G)
    out = []
    for i in range(T):
        t = i * DT
        if t < t_hit:
            out.append(p + [0, 0, 0.2 - 0.5 * G * t * t])
            continue
        s = 0.2 * math.cos(2 * math.pi * 5.0 * (t - t_hit)) * 0.5 ** ((t - t_hit) / 0.2)
        out.append(_squashed(p, s))
    return _traj(out)


def _splashes():
    """A water drop: falls 0.3 m, spreads 6x wide and 0.1x thin in 0.2 s, and the thin
    sheet goes on spreading slowly."""
    p = _ball(5)
    t_hit = math.sqrt(2 * 0.3 / G)
    out = []
    for i in range(T):
        t = i * DT
        s = min(1.0, max(0.0, (t - t_hit) / 0.2)) + 0.2 * max(0.0, t - t_hit - 0.2)
        q = p * [1 + 5 * s, 1 + 5 * s, 1 - 0.9 * s]
        q[:, 2] += R * (1 - 0.9 * s) + max(0.0, 0.3 - 0.5 * G * t * t)
        out.append(q)
    return _traj(out)


def _oozes():
    """Honey resting on the floor creeps out into a puddle: its radius doubles over the
    second at a steady 15 cm/s, still moving at the end (no fall)."""
    p = _ball(6) * [1, 1, 0.5]
    out = []
    for i in range(T):
        s = 1.0 * (i * DT)  # linear creep
        q = p * [1 + s, 1 + s, 1 / (1 + s) ** 2]
        q[:, 2] -= q[:, 2].min()
        out.append(q)
    return _traj(out)


def _keeps_shape():
    """A steel cube dropped 30 cm: it lands and stays, no rebound, no shape change."""
    p = _box(7, (0.3, 0.3, 0.3)) + [0, 0, 0.15]
    out = []
    for i in range(T):
        t = i * DT
        out.append(p + [0, 0, max(0.0, 0.3 - 0.5 * G * t * t)])
    return _traj(out)


def _crumbles():
    """A block of dry sand falls apart: 12 chunks slide off one another in 0.4 s and come
    to rest spread over the floor, apart."""
    rng = _rng(8)
    p = _box(8, (0.2, 0.2, 0.4), n=600) + [0, 0, 0.2]
    chunk = (
        np.floor((p[:, 0] + 0.1) / 0.1).clip(0, 1) * 6
        + np.floor((p[:, 1] + 0.1) / 0.1).clip(0, 1) * 3
        + np.floor(p[:, 2] / 0.134).clip(0, 2)
    ).astype(int)
    ang = rng.uniform(0, 2 * math.pi, 12)
    dist = rng.uniform(0.15, 0.45, 12)
    out = []
    for i in range(T):
        s = min(1.0, i * DT / 0.4)
        q = p.copy()
        for c in range(12):
            k = chunk == c
            if not k.any():
                continue
            base = q[k, 2].min()
            q[k, 0] += s * dist[c] * math.cos(ang[c])
            q[k, 1] += s * dist[c] * math.sin(ang[c])
            q[k, 2] -= s * base  # each chunk comes down to the floor
        out.append(q)
    return _traj(out)


def _squashes_flat():
    """A lump of clay pressed to half its height in 0.36 s; it keeps that shape."""
    p = _ball(9)
    out = []
    for i in range(T):
        s = min(1.0, i / 9)
        q = p * [1 + 0.25 * s, 1 + 0.25 * s, 1 - 0.5 * s]
        q[:, 2] += R * (1 - 0.5 * s)
        out.append(q)
    return _traj(out)


def _rod(seed: int) -> np.ndarray:
    return _box(seed, (0.6, 0.06, 0.06), n=600)


def _bent_rod(p: np.ndarray, hinge: float, angle: float, z0: float) -> np.ndarray:
    q = p.copy()
    free = q[:, 0] > hinge
    dx, dz = q[free, 0] - hinge, q[free, 2]
    q[free, 0] = hinge + dx * math.cos(angle) + dz * math.sin(angle)
    q[free, 2] = -dx * math.sin(angle) + dz * math.cos(angle)
    return q + [0, 0, z0]


def _bends():
    """A steel bar clamped at its left end, bent 30 deg at a hinge in 0.3 s; it stays bent."""
    p = _rod(10)
    return _traj([_bent_rod(p, -0.21, math.radians(30) * min(1.0, i / 8), 0.35) for i in range(T)])


def _vibrates():
    """A clamped rod whose free end vibrates at 4 Hz, 3 cm up and down, slowly damped."""
    p = _rod(11)
    out = []
    for i in range(T):
        t = i * DT
        a = 0.03 * math.sin(2 * math.pi * 4.0 * t) * math.exp(-t / 1.5)
        q = p + [0, 0, 0.35]
        q[:, 2] += a * ((q[:, 0] + 0.3) / 0.6) ** 2  # cantilever-like: the tip moves most
        out.append(q)
    return _traj(out)


def _heap():
    """A sand column 0.4 m tall collapses into a cone 0.12 m high."""
    p = _box(12, (0.2, 0.2, 0.4), n=800) + [0, 0, 0.2]
    out = []
    for i in range(T):
        s = min(1.0, i / 12)
        r = np.hypot(p[:, 0], p[:, 1])[:, None]
        ang = np.arctan2(p[:, 1], p[:, 0])[:, None]
        z = p[:, 2:3]
        r1 = r + (z / 0.4) * 0.25
        z1 = (0.4 - z) * 0.3 * (1 - r1 / 0.4).clip(0.1)
        rr, zz = r + s * (r1 - r), z + s * (z1 - z)
        out.append(np.hstack([rr * np.cos(ang), rr * np.sin(ang), zz]))
    return _traj(out)


def _rolls():
    """A rigid ball rolling across the floor at 1 m/s."""
    p = _ball(13)
    out = []
    for i in range(T):
        t = i * DT
        a = 1.0 * t / R  # rolling without slipping about y
        c, s = math.cos(a), math.sin(a)
        q = p @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        out.append(q + [1.0 * t, 0, R])
    return _traj(out)


WORDS: dict[str, tuple[Callable[[], dict[str, np.ndarray]], str]] = {
    "bounces high": (_bounces_high, "A rubber ball is dropped and bounces high."),
    "barely bounces": (_barely_bounces, "A ball is dropped and barely bounces."),
    "squashes and springs back": (
        _squash_recover,
        "A soft rubber ball squashes when it hits the floor and springs back.",
    ),
    "wobbles": (_wobbles, "A jelly cube lands and wobbles."),
    "splashes": (_splashes, "A drop of water falls and splashes across the floor."),
    "oozes": (_oozes, "Honey oozes slowly across the floor."),
    "keeps its shape": (_keeps_shape, "A steel cube lands and keeps its shape."),
    "crumbles": (_crumbles, "A block of dry sand crumbles and falls apart."),
    "squashes flat": (_squashes_flat, "A lump of clay is squashed flat and stays that way."),
    "bends": (_bends, "A steel bar fixed at one end bends permanently."),
    "vibrates gently": (_vibrates, "A thin rod fixed at one end gently vibrates."),
    "collapses into a heap": (_heap, "A sand column collapses into a heap."),
    "rolls": (_rolls, "A ball rolls across the floor."),
}
"""Motion word -> (its hand-made trajectory, a prompt that says it)."""


def hand_made() -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """The hand-made labelled set: ({word: measurements}, {word: prompt}); floor at z = 0."""
    meas = {w: measure(make(), floor=0.0) for w, (make, _) in WORDS.items()}
    return meas, {w: prompt for w, (_, prompt) in WORDS.items()}


def confusion(
    measurements: Mapping[str, Sequence[Mapping[str, Any]]],
    prompts: Mapping[str, Sequence[str]],
) -> np.ndarray:
    """``M[i, j]``: the mean score of the prompts of label ``i`` on the trajectories of
    label ``j`` (labels in ``prompts``' order; a prompt the score cannot read counts 0)."""
    names = list(prompts)
    M = np.zeros((len(names), len(names)))
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            s = [
                motion_adherence(p, measurements=m)["score"] or 0.0
                for m in measurements[b]
                for p in prompts[a]
            ]
            M[i, j] = float(np.mean(s)) if s else float("nan")
    return M


def margins(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row margins, column margins): how far each diagonal entry is above the highest
    other entry of its row (its prompt on other behaviours) and of its column (other
    prompts on its behaviour); all positive means diagonal-dominant both ways."""
    n = M.shape[0]
    rows = np.array([M[i, i] - np.delete(M[i], i).max() for i in range(n)])
    cols = np.array([M[i, i] - np.delete(M[:, i], i).max() for i in range(n)])
    return rows, cols


def clip_confusion(
    root: str, *, max_shards: int | None = None, phrasings: str = "held_out"
) -> tuple[np.ndarray, list[str], dict[str, int]]:
    """The confusion matrix over the motion groups of the clips under ``root``
    (``motionphysics prior data``): rows the groups' phrasings (``held_out``: the
    held-out ones, ``train``: the training ones) on the group's object noun, columns
    the clips of each measured group. Returns (M, group names, clips per group)."""
    from motionphysics.language.captions import GROUPS, HELD_OUT, TRAIN, group_prompt
    from motionphysics.priors.motion_data import load_clips

    table = HELD_OUT if phrasings == "held_out" else TRAIN
    d = load_clips(root, max_shards=max_shards)
    groups = list(GROUPS)
    meas: dict[str, list[tuple[str, dict[str, Any]]]] = {g: [] for g in groups}
    for i, g in enumerate(d["groups"]):
        if g in meas:
            traj = {"x": d["x"][i], "t": d["t"][i], "gravity": d["gravity"][i]}
            meas[g].append((d["specs"][i]["shape"], measure(traj, floor=float(d["ground"][i]))))
    M = np.zeros((len(groups), len(groups)))
    for a, ga in enumerate(groups):
        for b, gb in enumerate(groups):
            s = [
                motion_adherence(
                    group_prompt(ga, shape, k, held_out=table is HELD_OUT), measurements=m
                )["score"]
                or 0.0
                for shape, m in meas[gb]
                for k in range(len(table[ga]))
            ]
            M[a, b] = float(np.mean(s)) if s else float("nan")
    return M, groups, {g: len(v) for g, v in meas.items()}


def markdown(M: np.ndarray, names: Sequence[str], counts: Mapping[str, int] | None = None) -> str:
    """The matrix as a markdown table (diagonal in bold) and its two margins."""
    head = "| prompt \\ behaviour | " + " | ".join(
        f"{n}" + (f" ({counts[n]})" if counts else "") for n in names
    )
    lines = [head + " |", "|---|" + "---:|" * len(names)]
    for i, a in enumerate(names):
        cells = [f"**{v:.2f}**" if j == i else f"{v:.2f}" for j, v in enumerate(M[i])]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    rows, cols = margins(M)
    lines.append("")
    lines.append(
        f"Diagonal margin: rows min {rows.min():.3f} ({names[int(rows.argmin())]}), "
        f"columns min {cols.min():.3f} ({names[int(cols.argmin())]})."
    )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clips", action="append", default=[], metavar="DIR")
    ap.add_argument("--max-shards", type=int)
    ap.add_argument("--phrasings", choices=["held_out", "train"], default="held_out")
    args = ap.parse_args(argv)
    meas, prompts = hand_made()
    M = confusion({w: [m] for w, m in meas.items()}, {w: [p] for w, p in prompts.items()})
    print("### Hand-made trajectories (one per motion word)\n")
    print(markdown(M, list(prompts)))
    for root in args.clips:
        M, names, counts = clip_confusion(
            root, max_shards=args.max_shards, phrasings=args.phrasings
        )
        print(f"\n### Simulated clips: {root} ({args.phrasings} phrasings)\n")
        print(markdown(M, names, counts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
