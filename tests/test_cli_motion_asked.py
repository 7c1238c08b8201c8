"""A run without refinement says whether the motion its sentence asks for is the motion it
simulated: a config file through ``motionphysics run``, the summary lines, params.json's
``metrics.motion`` and the report. A foam block that the handbook's values keep rigid
is "not as asked" for "squashes flat" (and the summary says what moves it toward the
words); a lump of soft clay that does squash is not called a failure."""

from __future__ import annotations

import json

import yaml

from motionphysics.cli import main


def _config(prompt: str) -> dict:
    return {
        "scene": {
            "source": "builtin:cube",
            "scale": 0.3,
            "translate": [0, 0, 0.3],
            "max_particles": 600,
        },
        "prompt": prompt,
        "sim": {"grid": 20, "frames": 12, "frame_dt": 0.05, "substeps": "auto"},
        "camera": {"width": 32, "height": 32},
    }


def _run(tmp_path, capsys, prompt: str, material: dict | None = None):
    data = _config(prompt)
    if material is not None:
        data["material"] = material
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    summary = capsys.readouterr().out
    params = json.loads((out / "params.json").read_text())
    return summary, params, (out / "report.html").read_text()


def test_a_rigid_foam_asked_to_squash_flat_is_reported_not_as_asked(tmp_path, capsys):
    summary, params, report = _run(tmp_path, capsys, "A soft foam block falls and squashes flat")
    assert params["class"] == "foam" and params["optimise"] is None
    motion = params["metrics"]["motion"]
    assert motion["asked"] == "squashes_flat"
    assert motion["simulated"]["group"] != "squashes_flat"
    assert motion["simulated"]["measures"]["max_deform"] < 0.1  # it barely deformed
    assert motion["simulated"]["adherence"]["score"] < 0.5
    lines = motion["lines"]
    assert lines[0] == "motion asked: squashes flat (the prompt's motion words)"
    assert lines[1].startswith("  simulated: ") and lines[1].endswith("(not as asked)")
    assert "--prior motion" in lines[-1] and "material:" in lines[-1]
    for line in lines:
        assert line in summary
    assert "Motion asked for and simulated" in report and "not as asked" in report


def test_a_clay_lump_that_squashes_is_not_called_a_failure(tmp_path, capsys):
    summary, params, _ = _run(tmp_path, capsys, "A lump of soft clay is dropped and squashes flat")
    motion = params["metrics"]["motion"]
    assert params["class"] == "plasticine" and motion["asked"] == "squashes_flat"
    assert motion["simulated"]["measures"]["max_deform"] > 0.2
    assert "not as asked" not in motion["lines"][1]
    assert motion["lines"][1] in summary
    assert not any("--prior motion" in line for line in motion["lines"])


def test_a_prompt_without_motion_words_gets_no_motion_lines(tmp_path, capsys):
    summary, params, _ = _run(tmp_path, capsys, "A rubber cube")
    assert "motion" not in params["metrics"]
    assert "motion asked:" not in summary


def test_quiet_prints_nothing_but_params_keep_the_record(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(_config("A soft foam block falls and squashes flat")))
    out = tmp_path / "run"
    assert main(["--quiet", "run", str(cfg), "--out", str(out)]) == 0
    assert capsys.readouterr().out == ""
    assert json.loads((out / "params.json").read_text())["metrics"]["motion"]["lines"]


def test_a_fluid_that_collapses_and_splashes_is_asked_to_splash(tmp_path, capsys):
    """ "Crumbles" is the granular word for a collapse; water cannot show it, so the prompt
    is read without it: the splash is what was asked (it was read as crumbling, and a
    splashing dam break was called "not as asked")."""
    data = _config("A block of water collapses and splashes across the floor")
    data["material"] = {"class": "newtonian", "density": 1000, "mu": 0.001, "kappa": 2.2e9}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    assert main(["--quiet", "run", str(cfg), "--out", str(out)]) == 0
    motion = json.loads((out / "params.json").read_text())["metrics"]["motion"]
    assert motion["asked"] == "splashes"


def test_a_weak_second_reading_is_no_reading(tmp_path, capsys):
    """A paste that "piles up" is nearest "crumbles", which a paste cannot show; without
    it the nearest group is a weak match (a bounce, 0.50): no motion group is claimed,
    and eval's adherence to the words ("piles up") is what the run says."""
    paste = {"class": "non_newtonian", "density": 1200, "mu": 1.0, "kappa": 2.0e9}
    paste.update({"tau_Y": 100.0, "eta": 0.5, "n": 0.6})
    prompt = "Toothpaste is squeezed out, falls onto the surface and piles up."
    summary, params, _ = _run(tmp_path, capsys, prompt, paste)
    lines = summary.splitlines()
    asked = next(s for s in lines if s.startswith("motion asked:"))
    assert asked.startswith("motion asked: 'piles up' (no motion group of the motion prior")
    motion = params["metrics"]["motion"]
    assert motion["asked"] is None and motion["asked_words"] == ["piles up"]
    score = motion["simulated"]["adherence"]["score"]
    assert f"  motion adherence (eval, 0..1): {score:.2f}" in lines


def test_a_motion_no_group_holds_is_read_in_evals_words(tmp_path, capsys):
    """ "Bends" is nearest "squashes flat" by its sentence embedding (0.72), but it is no
    word of a squash: the run reads the motion as eval's words and claims no group."""
    rubber = {"class": "elastic", "density": 1000, "E": 1.0e6, "nu": 0.3}
    prompt = "A copper rod falls and bends when it hits the floor."
    summary, params, _ = _run(tmp_path, capsys, prompt, rubber)
    asked = next(s for s in summary.splitlines() if s.startswith("motion asked:"))
    assert "squashes flat" not in asked and "'bends'" in asked
    motion = params["metrics"]["motion"]
    assert motion["asked"] is None and motion["asked_words"] == ["bends"]
    assert any(e.startswith("bends") for e in motion["simulated"]["adherence"]["explanations"])
