"""Hand-made motion clips in the shard layout of ``priors.motion_data`` (no simulation),
for fast tests of the motion prior's data loading, training and measures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

T = 16
K = 32

# measures that satisfy each motion group's rule (language.captions.motion_group)
MEASURES = {
    "bounces_high": dict(rebound=0.5, final_height=1.0, min_height=0.9, spread=1.0,
                         max_spread=1.0, deform=0.01, max_deform=0.02, wobble=0.0,
                         late_speed=0.5, fell=1.0),
    "splashes": dict(rebound=0.0, final_height=0.2, min_height=0.2, spread=3.0,
                     max_spread=3.0, deform=0.5, max_deform=0.5, wobble=0.0,
                     late_speed=0.1, fell=1.0),
    "keeps_shape": dict(rebound=0.0, final_height=1.0, min_height=1.0, spread=1.0,
                        max_spread=1.0, deform=0.005, max_deform=0.01, wobble=0.0,
                        late_speed=0.0, fell=1.0),
}  # fmt: skip


def clip(group: str, rng: np.random.Generator, size: float = 0.2):
    """(x [T,K,3], F [T,K,3,3], t [T]) of a hand-made clip showing ``group``."""
    rest = rng.uniform(-0.5, 0.5, (K, 3)) * size
    rest[:, 2] += 0.5 * size + 0.1
    t = np.arange(T) * 0.05
    fall = np.minimum(0.5 * 9.8 * t**2, 0.1)
    x = np.repeat(rest[None], T, 0).copy()
    F = np.repeat(np.eye(3)[None, None], T, 0).repeat(K, 1).copy()
    c = rest.mean(0)
    for i in range(T):
        x[i, :, 2] -= fall[i]
        if group == "bounces_high" and fall[i] >= 0.1:
            x[i, :, 2] += 0.06 * abs(np.sin(8.0 * (t[i] - 0.14)))
        if group == "splashes" and fall[i] >= 0.1:
            k = 1.0 + 3.0 * min(1.0, 4.0 * (t[i] - 0.14))
            s = np.diag([k, k, 1.0 / k**2])
            x[i] = (x[i] - c) @ s.T + c
            F[i] = s
    return x.astype(np.float32), F.astype(np.float32), t.astype(np.float32)


def write_shards(root: Path, groups: list[str], seed: int = 0, shape: str = "sphere") -> Path:
    """One shard holding a clip per entry of ``groups``."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    xs, Fs, ts = zip(*(clip(g, rng) for g in groups), strict=True)
    np.savez(
        root / "shard-00000.npz",
        x=np.stack(xs),
        F=np.stack(Fs),
        v=np.zeros((len(groups), T, K, 3), np.float16),
        t=np.stack(ts),
        ground=np.zeros(len(groups), np.float32),
        gravity=np.tile(np.array([0.0, 0.0, -9.8], np.float32), (len(groups), 1)),
        measures=np.array(json.dumps([MEASURES[g] for g in groups])),
        groups=np.array(json.dumps(list(groups))),
        attempts=np.ones(len(groups), np.int32),
        specs=np.array(
            json.dumps([{"index": i, "cls": "elastic", "shape": shape} for i in range(len(groups))])
        ),
        failed=np.array("[]"),
    )
    return root
