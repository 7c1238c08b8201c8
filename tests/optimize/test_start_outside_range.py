"""A start value a person wrote outside the handbook range is used as written, so its
refinement starts there: the optimised range widens to hold it, with one line saying so
(before, the run stopped with a traceback from the theta map)."""

from __future__ import annotations

import json

import pytest
import torch
import yaml

from motionphysics.cli import main
from motionphysics.materials.theta import Parameterisation
from motionphysics.optimize.fit import start_ranges


def test_a_widened_range_holds_its_start_and_bounds_every_theta():
    pm = Parameterisation("newtonian", ["mu", "kappa"], ranges={"kappa": (1.0e5, 5.0e9)})
    theta = pm.to_theta({"mu": 1.0, "kappa": 1.0e5})
    back = pm.from_theta(theta)
    assert float(back["kappa"]) == pytest.approx(1.0e5, rel=1e-4)  # at the bound (EPS)
    assert float(back["mu"]) == pytest.approx(1.0, rel=1e-9)
    for t in (-50.0, 0.0, 50.0):
        k = float(pm.from_theta(torch.tensor([0.0, t], dtype=torch.float64))["kappa"])
        assert 1.0e5 * (1 - 1e-9) <= k <= 5.0e9 * (1 + 1e-9)
    with pytest.raises(ValueError, match="outside"):
        Parameterisation("newtonian", ["kappa"]).to_theta({"kappa": 1.0e5})
    with pytest.raises(ValueError, match="not among"):
        Parameterisation("newtonian", ["mu"], ranges={"kappa": (1.0, 2.0)})


def test_start_ranges_widen_only_what_lies_outside():
    ranges, lines = start_ranges("newtonian", ["mu", "kappa"], {"mu": 1.0, "kappa": 1.0e5})
    assert ranges == {"kappa": (1.0e5, 5.0e9)}
    assert len(lines) == 1 and "kappa starts at 1e5 Pa" in lines[0]
    assert "refined within 1e5 - 5e9 Pa" in lines[0]
    assert start_ranges("newtonian", ["mu"], {"mu": 1.0}) == ({}, [])


def test_a_refined_run_from_a_start_outside_the_handbook_range(tmp_path, capsys):
    """Through a config file: water with a bulk modulus 10^4 below the handbook's, refined
    with the motion prior: it runs, says in one line where it refines, and starts there."""
    cfg = {
        "scene": {"source": "builtin:cube", "scale": 0.3, "translate": [0, 0, 0.25]},
        "prompt": "A block of water collapses and splashes across the floor of a tank.",
        "material": {"class": "newtonian", "density": 1000.0, "mu": 1.0, "kappa": 1.0e5},
        "sim": {"grid": 12, "frames": 9, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 32, "height": 32},
        "optimize": {"iterations": 2, "boost": 1, "prior": "motion", "loss": "lmd"},
    }
    cfg["scene"]["max_particles"] = 300
    path = tmp_path / "water.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    line = (
        "warning: optimize: kappa starts at 1e5 Pa, outside the handbook range of "
        "newtonian (1e9 - 5e9 Pa); it is refined within 1e5 - 5e9 Pa"
    )
    assert line in err.splitlines()
    params = json.loads((out / "params.json").read_text())
    kappa = params["optimise"]["parameters"]["kappa"]
    assert kappa["initial"] == pytest.approx(1.0e5, rel=1e-4)
    assert 1.0e5 * (1 - 1e-4) <= kappa["final"] <= 5.0e9


def test_a_fit_from_a_start_outside_the_handbook_range(tmp_path, capsys):
    """Through a config file: ``fit`` of an elastic sphere whose E is written at 300 Pa,
    below the elastic handbook range, against a reference made at that E: it runs, says
    where it refines in one line, and starts there (``fit.start``, the log)."""
    cfg = {
        "scene": {"source": "builtin:sphere", "scale": 0.3, "translate": [0, 0, 0.2]},
        "material": {"class": "elastic", "density": 1000.0, "E": 300.0, "nu": 0.4},
        "sim": {"grid": 12, "frames": 4, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
        "optimize": {"global_search": False, "params": ["E"]},
    }
    cfg["scene"]["max_particles"] = 120
    path = tmp_path / "soft.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["--quiet", "simulate", str(path), "--out", str(tmp_path / "ref")]) == 0
    out = tmp_path / "fit"
    ref = str(tmp_path / "ref" / "trajectory.npz")
    assert main(["fit", str(path), "--reference", ref, "--out", str(out), "--iters", "2"]) == 0
    err = capsys.readouterr().err.splitlines()
    lines = [x for x in err if x.startswith("warning: optimize: E starts at 300 Pa")]
    assert len(lines) == 1 and "it is refined within 300 - " in lines[0], err
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert log[0]["params"]["E"] == pytest.approx(300.0, rel=1e-3)
