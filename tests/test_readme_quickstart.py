"""The README's first screen: the two commands, the gallery and "your scene and your sentence
in five steps", whose config runs through `motionphysics run` as printed (at a small size).

What the README says about the ground is checked against what a run writes, so the first
thing a newcomer reads cannot drift from the program.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FIRST_SCREEN = 60


def first_screen() -> str:
    return "\n".join(README.read_text(encoding="utf-8").splitlines()[:FIRST_SCREEN])


def five_step_config() -> dict:
    """The YAML config of the five steps (the first ```yaml block of the first screen)."""
    m = re.search(r"```yaml\n(.*?)```", first_screen(), re.S)
    assert m, f"no YAML config in the README's first {FIRST_SCREEN} lines"
    return yaml.safe_load(m.group(1))


def test_first_screen_holds_the_two_commands_first():
    text = first_screen()
    commands = re.findall(r"^(make \w+)", text, re.M)
    assert commands[:2] == ["make demo", "make test"], commands


def test_first_screen_holds_the_five_steps_in_order():
    text = first_screen()
    assert re.search(r"^## .*five steps", text, re.M | re.I), "no five-steps heading"
    steps = [int(n) for n in re.findall(r"^(\d)\. ", text, re.M)]
    assert steps == [1, 2, 3, 4, 5], steps
    # The steps say what a newcomer cannot guess: the ground, free space, the camera.
    assert "z = 0" in text and "boundary_conditions: []" in text and "camera" in text
    assert "motionphysics run" in text and "motionphysics init" in text


def test_first_screen_shows_the_gallery_and_every_picture_exists():
    pictures = re.findall(r"!\[[^\]]*\]\((docs/gallery/[^)\s]+\.gif)\)", first_screen())
    assert len(pictures) >= 8, pictures
    missing = [p for p in pictures if not (ROOT / p).is_file()]
    assert not missing, missing


def test_first_screen_says_what_you_get_and_how_long():
    text = first_screen()
    assert "runs/demo" in text and "video" in text and "report.html" in text
    assert re.search(r"\d+ min", text), "no duration on the first screen"


def test_the_five_step_config_leaves_the_material_and_the_ground_to_the_defaults():
    from motionphysics.config import config_from_dict

    d = five_step_config()
    assert "material" not in d, "the five steps let the words decide the material"
    assert "boundary_conditions" not in d, "the five steps use the default ground"
    cfg = config_from_dict(d, "README.md")
    assert cfg.material.class_ is None and cfg.boundary_conditions is None


def _run_small(d: dict, out: Path, grid: int = 16) -> subprocess.CompletedProcess:
    """``motionphysics run`` of config ``d`` at a test size (what it is, not how finely)."""
    d = json.loads(json.dumps(d))
    d.setdefault("scene", {})["max_particles"] = 600
    d.setdefault("sim", {}).setdefault("frames", 8)
    d["sim"]["grid"] = grid
    d.setdefault("camera", {}).update({"width": 48, "height": 48})
    cfg = out.parent / f"{out.name}.yaml"
    cfg.write_text(yaml.safe_dump(d), encoding="utf-8")
    return subprocess.run(
        [sys.executable, "-m", "motionphysics", "--quiet", "run", str(cfg), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_the_five_step_config_runs_and_gets_what_the_readme_promises(tmp_path):
    out = tmp_path / "my"
    proc = _run_small(five_step_config(), out, grid=32)
    assert "domain wall" not in proc.stderr, proc.stderr  # room enough, as the config says
    assert proc.returncode == 0, proc.stderr[-3000:]
    params = json.loads((out / "params.json").read_text())
    # Step 2: the words decide (the kb, from the prompt), and the README names the result.
    assert params["class"] == "elastic"
    assert params["provenance"]["backend"] == "kb"
    assert params["params"]["E"] == pytest.approx(1.5e4)
    assert "E 15 kPa" in first_screen()
    # Step 3: a frictional floor, friction 0.3, at z = 0, written to run.yaml.
    run = yaml.safe_load((out / "run.yaml").read_text())
    floors = [
        bc
        for bc in run["boundary_conditions"]
        if bc["type"] == "surface_collider" and list(bc["normal"]) == [0.0, 0.0, 1.0]
    ]
    assert len(floors) == 1, run["boundary_conditions"]
    assert floors[0]["point"][2] == 0.0 and floors[0]["mode"] == "frictional"
    assert (floors[0]["friction"] or 0.3) == pytest.approx(0.3)
    assert "friction 0.3" in first_screen()
    # Step 5: the files the README points at.
    assert (out / "video.mp4").stat().st_size > 0 and (out / "report.html").is_file()
    # The object fell onto that floor and stayed on it (it did not fall through).
    with np_load(out / "trajectory.npz") as z:
        x = z["x"]
    assert x[0, :, 2].min() > 0.02 and x[-1, :, 2].min() > -0.02
    assert x[-1, :, 2].mean() < x[0, :, 2].mean() - 0.02


def test_free_space_is_what_the_readme_says(tmp_path):
    """``boundary_conditions: []``: no ground; with room in ``sim.domain`` (whose faces are
    walls, as step 3 says) the object falls freely through z = 0."""
    text = first_screen()
    assert "sim.domain" in text and "walls" in text
    d = five_step_config()
    d["boundary_conditions"] = []
    d["sim"] = {"frames": 10, "domain": [[-0.3, -0.3, -0.6], [0.3, 0.3, 0.6]]}
    out = tmp_path / "free"
    proc = _run_small(d, out, grid=24)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = yaml.safe_load((out / "run.yaml").read_text())
    assert run["boundary_conditions"] == []
    with np_load(out / "trajectory.npz") as z:
        x, t = z["x"].astype(float), z["t"].astype(float)
    drop = x[0, :, 2].mean() - x[:, :, 2].mean(axis=1)
    np.testing.assert_allclose(drop, 0.5 * 9.8 * (t - t[0]) ** 2, atol=0.02)
    assert x[-1, :, 2].max() < 0.0  # all of it below where the default floor would be


def np_load(path: Path):
    return np.load(path, allow_pickle=False)
