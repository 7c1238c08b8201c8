"""Objects that start inside each other are told so, through ``motionphysics simulate
CONFIG``: two balls written without ``translate`` both sat at the origin, and the run
showed one ball (two superimposed, falling as one) without a word.

* the same place, or half a radius apart: exit 2 with one line naming both objects and
  ``translate``;
* touching, apart, or a ball inside a hollow shell's empty middle: the run goes on.
"""

from __future__ import annotations

import numpy as np
import yaml

from motionphysics.cli import main
from motionphysics.scene.prepare import object_overlap

RUBBER = {"class": "elastic", "density": 1000.0, "E": 1.0e6, "nu": 0.3}


def _config(xa: float, xb: float) -> dict:
    def ball(name, x):
        return {
            "name": name,
            "source": "builtin:sphere",
            "scale": 0.2,
            "translate": [x, 0.0, 0.3],
            "max_particles": 500,
            "material": dict(RUBBER),
        }

    return {
        "prompt": "Two rubber balls fall onto the floor.",
        "objects": [ball("red", xa), ball("blue", xb)],
        "sim": {"grid": 20, "frames": 1, "frame_dt": 0.02, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }


def _simulate(tmp_path, capsys, data, name):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    capsys.readouterr()
    rc = main(["simulate", str(path), "--out", str(tmp_path / name)])
    err = capsys.readouterr().err
    return rc, [s for s in err.splitlines() if "start inside each other" in s]


def test_two_objects_at_the_same_place_stop_the_run_with_one_line(tmp_path, capsys):
    for name, (xa, xb) in {"same": (0.0, 0.0), "half": (-0.025, 0.025)}.items():
        rc, lines = _simulate(tmp_path, capsys, _config(xa, xb), name)
        assert rc == 2 and len(lines) == 1, (name, lines)
        line = lines[0]
        assert line.startswith("motionphysics: error: objects: ")
        assert "blue" in line and "red" in line and "`translate`" in line
    assert "(100 % of blue's particles" in _simulate(tmp_path, capsys, _config(0, 0), "s2")[1][0]


def test_touching_or_apart_runs(tmp_path, capsys):
    for name, (xa, xb) in {"touching": (-0.1, 0.1), "apart": (-0.3, 0.3)}.items():
        assert _simulate(tmp_path, capsys, _config(xa, xb), name) == (0, [])


def _sphere_shell(n: int, r: float, rng) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return r * v / np.linalg.norm(v, axis=1, keepdims=True)


def test_the_overlap_of_hand_made_objects():
    rng = np.random.default_rng(0)
    ball = rng.uniform(-0.1, 0.1, size=(4000, 3))
    ball = ball[np.linalg.norm(ball, axis=1) < 0.1]
    shell = _sphere_shell(6000, 0.5, rng)  # a hollow shell 1 m across, the ball inside
    cases = {
        "same place": (ball, ball, True),
        "half a radius apart": (ball, ball + [0.05, 0, 0], True),
        "touching": (ball, ball + [0.2, 0, 0], False),
        "ball in the shell's empty middle": (shell, ball, False),
    }
    for name, (a, b, stops) in cases.items():
        p = np.concatenate([a, b])
        oid = np.repeat([0, 1], [len(a), len(b)])
        line = object_overlap(p, oid, 0.02, ["a", "b"])
        assert (line is not None) == stops, (name, line)
