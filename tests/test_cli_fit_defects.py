"""Two of ``fit``'s small defects (issue 27, item 5), through the command line.

- By default ``fit`` leaves Poisson's ratio at the config's value (it drifted 0.4 ->
  0.155 on a reference made with 0.4 when fitted beside E) and says so in one line.
- A fit interrupted in its global stage says, on ``--resume``, that it redoes the global
  search and then the gradient stage (it used to say "restarting from 'simulate' at
  frame 0", which is not what it does), and then finishes.

One tiny elastic reference (120 particles, grid 12, 4 frames) made by ``simulate``.
"""

from __future__ import annotations

import json

import pytest
import yaml

from motionphysics.cli import main

TRUE = {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.4}


def _config(material: dict, **optimize) -> dict:
    return {
        "scene": {
            "source": "builtin:sphere",
            "scale": 0.3,
            "translate": [0, 0, 0.2],
            "max_particles": 120,
        },
        "material": material,
        "sim": {
            "grid": 12,
            "frames": 4,
            "frame_dt": 0.04,
            "substeps": "auto",
            "domain": [[-0.4, -0.4, -0.1], [0.4, 0.4, 0.7]],
        },  # fmt: skip
        "boundary_conditions": [
            {
                "type": "surface_collider",
                "point": [0, 0, 0],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": 0.4,
            },  # fmt: skip
            {"type": "bounding_box"},
        ],
        "camera": {"width": 16, "height": 16},
        "optimize": {"global_points": 3, "global_refine": 0, **optimize},
    }


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("fitdefects")
    (d / "true.yaml").write_text(yaml.safe_dump(_config(TRUE)))
    assert main(["--quiet", "simulate", str(d / "true.yaml"), "--out", str(d / "ref")]) == 0
    start = dict(TRUE, E=3.0e5)  # 3x stiffer; nu as the reference's
    (d / "start.yaml").write_text(yaml.safe_dump(_config(start)))
    return d


def _fit(d, out, *extra):
    return main(
        [
            "fit",
            str(d / "start.yaml"),
            "--reference",
            str(d / "ref" / "trajectory.npz"),
            "--out",
            str(out),
            "--iters",
            "2",
            *extra,
        ]  # fmt: skip
    )


def test_fit_leaves_nu_alone_unless_asked_and_says_so(reference, tmp_path, capsys):
    assert _fit(reference, tmp_path / "fit") == 0
    captured = capsys.readouterr()
    said = [ln for ln in captured.out.splitlines() if "stays at the config" in ln]
    assert len(said) == 1 and "fit optimises E; nu 0.4 stays" in said[0], captured.out
    assert "optimize.params" in said[0]
    p = json.loads((tmp_path / "fit" / "params.json").read_text())
    assert p["fit"]["optimised"] == ["E"]
    assert p["params"]["nu"] == TRUE["nu"]  # untouched: exactly the config's value
    assert p["params"]["E"] != 3.0e5  # E itself was fitted

    # asking for nu fits it (the default is a default, not a ban)
    cfg = _config(dict(TRUE, E=3.0e5), params=["E", "nu"])
    (tmp_path / "both.yaml").write_text(yaml.safe_dump(cfg))
    rc = main(
        [
            "--quiet",
            "fit",
            str(tmp_path / "both.yaml"),
            "--reference",
            str(reference / "ref" / "trajectory.npz"),
            "--out",
            str(tmp_path / "both"),
            "--iters",
            "1",
            "--no-global",
        ]  # fmt: skip
    )
    assert rc == 0
    p = json.loads((tmp_path / "both" / "params.json").read_text())
    assert p["fit"]["optimised"] == ["E", "nu"]
    assert "stays at the config" not in p["fit"]["message"]


def test_fit_interrupted_in_its_global_stage_resumes_it_and_says_so(
    reference, tmp_path, capsys, monkeypatch
):
    import motionphysics.optimize.fit as fit

    real = fit.global_search
    calls = {"n": 0}

    def interrupted(problem, opt, log_path=None, *, observer=None):
        calls["n"] += 1
        raise KeyboardInterrupt

    out = tmp_path / "fit"
    monkeypatch.setattr(fit, "global_search", interrupted)
    assert _fit(reference, out, "--quiet") == 130
    p = json.loads((out / "params.json").read_text())
    assert p["partial"] is True and p["stage"] == "global search" and calls["n"] == 1
    capsys.readouterr()

    monkeypatch.setattr(fit, "global_search", real)
    assert _fit(reference, out, "--quiet", "--resume") == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "resuming" in ln]
    assert len(lines) == 1, lines
    assert "'global search'" in lines[0]
    assert "restarting the global search from its first candidate" in lines[0]
    assert "gradient stage from iteration 0 of 2" in lines[0]
    assert "'simulate' at frame 0" not in lines[0]  # the old, untrue message
    p = json.loads((out / "params.json").read_text())
    assert p["partial"] is False and p["status"] == "complete"
    stages = [r["stage"] for r in p["history"]]
    assert stages.count("gradient") == 2 and stages[0] == "global"  # it did what it said
