"""One run-directory writer for run, simulate and fit: the same params.json schema
(key sets compared), the same report and summary format, and scene.ply (the prepared
rest splats) that our reader loads back to the same splats."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml

from motionphysics.cli import main
from motionphysics.io.writer import PARAMS_KEYS, PARAMS_SCHEMA, format_value

TINY = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.2],
        "max_particles": 150,
    },
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "sim": {"grid": 10, "frames": 3, "frame_dt": 0.02, "substeps": 10},
    "boundary_conditions": [
        {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "sticky"},
        {"type": "bounding_box"},
    ],
    "camera": {"width": 24, "height": 24},
    "optimize": {"params": ["E"], "boost": 1, "lr": 0.2, "iterations": 2, "warmup": 0},
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("writer")
    full = {**TINY, "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3}}
    (d / "full.yaml").write_text(yaml.safe_dump(full))
    start = {**TINY, "material": {"class": "elastic", "density": 1000.0, "E": 1.0e8, "nu": 0.3}}
    (d / "start.yaml").write_text(yaml.safe_dump(start))
    (d / "prompt.yaml").write_text(yaml.safe_dump({**TINY, "material": {"nu": 0.3}}))
    assert main(["--quiet", "simulate", str(d / "full.yaml"), "--out", str(d / "simulate")]) == 0
    assert main(["--quiet", "run", str(d / "prompt.yaml"), "--out", str(d / "run")]) == 0
    ref = d / "simulate" / "trajectory.npz"
    assert (
        main(
            [
                "--quiet",
                "fit",
                str(d / "start.yaml"),
                "--reference",
                str(ref),
                "--out",
                str(d / "fit"),
            ]
        )
        == 0
    )
    return d


def _params(path):
    return json.loads((path / "params.json").read_text())


def test_params_json_has_one_schema_for_every_command(runs):
    keys = {c: set(_params(runs / c)) for c in ("run", "simulate", "fit")}
    assert keys["run"] == keys["simulate"] == keys["fit"] == set(PARAMS_KEYS)
    for c in ("run", "simulate", "fit"):
        p = _params(runs / c)
        assert p["schema"] == PARAMS_SCHEMA and p["command"] == c and p["partial"] is False
        assert set(p["sim_context"]) == set(_params(runs / "run")["sim_context"])
        for f in ("report.html", "scene.ply", "trajectory.npz", "video.mp4", "plots/slice_row.png"):
            assert (runs / c / f).is_file(), (c, f)
    assert _params(runs / "run")["fit"] is None and _params(runs / "simulate")["reference"] is None
    fit = _params(runs / "fit")
    assert fit["fit"]["iterations_run"] == 2 and fit["initial"]["params"]["E"] == 1.0e8
    assert fit["reference"]["kind"] == "trajectory"
    # the report of a fit is the same page as a run's: material table, video, plots
    html = (runs / "fit" / "report.html").read_text()
    assert "elastic" in html and "<video" in html and "plots/loss.png" in html


def test_scene_ply_loads_back_to_the_prepared_splats(runs):
    from motionphysics.config import config_from_dict
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare

    data = {**TINY, "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3}}
    cfg = config_from_dict(data, "test")
    sim_scene = prepare(
        load_scene(cfg.scene.source), cfg.scene, cfg.sim, list(cfg.boundary_conditions)
    )
    back = load_scene(str(runs / "simulate" / "scene.ply"))
    want = sim_scene.splats
    assert back.num == want.num
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
        assert torch.equal(getattr(back, name).float(), getattr(want, name).float()), name
    # and with trajectory.npz it is all a viewer needs to re-deform them
    with np.load(runs / "simulate" / "trajectory.npz") as z:
        assert {"x", "F", "splat_parent", "splat_offset"} <= set(z.files)
        assert z["splat_parent"].shape == (want.num,)


def test_every_command_prints_the_same_formatted_summary(runs, capsys):
    d = runs
    ref = d / "simulate" / "trajectory.npz"
    assert (
        main(
            [
                "fit",
                str(d / "start.yaml"),
                "--reference",
                str(ref),
                "--out",
                str(d / "fit2"),
                "--iters",
                "1",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "fit:" in out and "material:  elastic" in out and "timings:" in out
    # formatted like run's: 1.000e+07 style, never a raw float such as 10000093.0
    line = next(x for x in out.splitlines() if x.strip().startswith("E "))
    assert "e+0" in line and "(simulation:" in line
    assert format_value(10000093.0) == "1.000e+07" and format_value(0.3) == "0.3"
