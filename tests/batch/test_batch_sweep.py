"""Sweep files: expansion (product, zip), stable ids, validation of every job before
anything runs (exit 2, one line naming the axis and the value), --dry-run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from motionphysics.batch import job_id, load_sweep, plan_jobs
from motionphysics.cli import main
from motionphysics.errors import UserInputError

TINY = Path(__file__).parent / "data" / "tiny.yaml"


def _sweep(tmp_path: Path, text: str, name: str = "sweep.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    return err


def test_product_order_values_and_configs(tmp_path):
    p = _sweep(
        tmp_path,
        f"base: {TINY}\naxes:\n  material.E: [2.0e+7, 4.0e+7, 8.0e+7]\n  optimize.seed: [0, 1]\n",
    )
    sw = load_sweep(p, tmp_path / "out")
    assert [j.values for j in sw.jobs] == [
        {"material.E": e, "optimize.seed": s} for e in (2e7, 4e7, 8e7) for s in (0, 1)
    ]
    for j in sw.jobs:  # each job's config is the base with its values applied
        assert j.config.material.E == j.values["material.E"]
        assert j.config.optimize.seed == j.values["optimize.seed"]
        assert j.config.sim.grid == 8 and j.config.scene.max_particles == 300
    assert len({j.id for j in sw.jobs}) == 6
    assert len({j.config_hash for j in sw.jobs}) == 6
    assert sw.job_dir(sw.jobs[0]) == tmp_path / "out" / "jobs" / sw.jobs[0].id
    assert not (tmp_path / "out").exists()  # loading writes nothing


def test_zip_advances_together_and_crosses_the_rest(tmp_path):
    p = _sweep(
        tmp_path,
        f"base: {TINY}\n"
        "axes:\n"
        "  prompt: ['A rubber ball bounces.', 'A steel ball hits the ground.']\n"
        "  material.E: [2.0e+7, 9.0e+10]\n"
        "  optimize.seed: [0, 1, 2]\n"
        "zip: [[prompt, material.E]]\n",
    )
    sw = load_sweep(p)
    assert len(sw.jobs) == 6
    pairs = {(j.values["prompt"], j.values["material.E"]) for j in sw.jobs}
    assert pairs == {("A rubber ball bounces.", 2e7), ("A steel ball hits the ground.", 9e10)}
    assert sorted(j.values["optimize.seed"] for j in sw.jobs) == [0, 0, 1, 1, 2, 2]
    assert sw.out == Path("runs") / "sweep"  # default: runs/<sweep name>


def test_ids_are_stable_readable_and_order_independent(tmp_path):
    a = job_id(
        {"prompt": "A rubber bird bounces.", "scene.source": "builtin:bird", "optimize.seed": 1}
    )
    b = job_id(
        {"optimize.seed": 1, "scene.source": "builtin:bird", "prompt": "A rubber bird bounces."}
    )
    assert a == b
    assert a.startswith("1_a-rubber-bird-bounces_builtin-bird-")
    assert job_id({"optimize.seed": 2}) != job_id({"optimize.seed": 1})
    # Values whose slugs coincide still get different ids (the hash covers the values).
    assert job_id({"prompt": "a b"}) != job_id({"prompt": "a-b"})
    assert job_id({"scene.source": "/data/x/donut.ply"}).startswith("donut.ply-")
    assert job_id({}).startswith("job-")


def test_out_key_is_relative_to_the_sweep_file_and_flag_wins(tmp_path):
    (tmp_path / "sub").mkdir()
    p = _sweep(tmp_path / "sub", f"base: {TINY}\nout: results/here\naxes: {{optimize.seed: [0]}}\n")
    assert load_sweep(p).out == tmp_path / "sub" / "results" / "here"
    assert load_sweep(p, tmp_path / "x").out == tmp_path / "x"


def test_inline_base_and_paths_relative_to_the_sweep_file(tmp_path):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "a.ply").write_bytes(b"")  # only its existence matters here
    p = _sweep(
        tmp_path,
        "base:\n  sim: {grid: 8, frames: 2}\n  scene: {source: scenes/a.ply}\n"
        "axes:\n  camera.width: [32, 48]\n",
    )
    sw = load_sweep(p)
    assert [j.config.camera.width for j in sw.jobs] == [32, 48]
    assert sw.jobs[0].config.scene.source == str((tmp_path / "scenes" / "a.ply").resolve())
    # An axis over files: also relative to the sweep file.
    p2 = _sweep(
        tmp_path, f"base: {TINY}\naxes:\n  scene.source: [scenes/a.ply, builtin:cube]\n", "s2.yaml"
    )
    sources = [j.config.scene.source for j in load_sweep(p2).jobs]
    assert sources == [str((tmp_path / "scenes" / "a.ply").resolve()), "builtin:cube"]


def test_changed_base_keeps_ids_and_changes_hashes(tmp_path):
    base = tmp_path / "base.yaml"
    base.write_text(TINY.read_text())
    p = _sweep(tmp_path, "base: base.yaml\naxes: {optimize.seed: [0, 1]}\n")
    before = load_sweep(p).jobs
    base.write_text(TINY.read_text().replace("frames: 2", "frames: 3"))
    after = load_sweep(p).jobs
    assert [j.id for j in before] == [j.id for j in after]
    assert all(a.config_hash != b.config_hash for a, b in zip(before, after, strict=True))


@pytest.mark.parametrize(
    ("axes", "expect"),
    [
        ("sim.grids: [8, 16]", ["sweep.yaml", "axes.sim.grids", "value 8", "unknown key"]),
        ("sim.frames: [2, -1]", ["sweep.yaml", "axes.sim.frames", "value -1", "sim.frames"]),
        ("scene.source: [builtin:cube, 3]", ["axes.scene.source", "value 3", "scene.source"]),
        ("prompt.text: [a]", ["axes.prompt.text", '"a"', "prompt"]),
        ("optimize.prior: [none, magic]", ["axes.optimize.prior", '"magic"']),
        # the removed pixel prior: refused with the reason, not as an unknown name
        (
            "optimize.prior: [none, tiny]",
            ["axes.optimize.prior", '"tiny"', "pixel prior was removed", "use optimize.prior"],
        ),
    ],
)
def test_bad_axis_key_or_value_is_exit_2_one_line(tmp_path, capsys, axes, expect):
    p = _sweep(tmp_path, f"base: {TINY}\naxes:\n  optimize.seed: [0, 1]\n  {axes}\n")
    out = tmp_path / "out"
    assert main(["batch", str(p), "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    for piece in expect:
        assert piece in err, err
    assert not out.exists()  # nothing ran, nothing was written


def test_invalid_only_in_combination_names_the_job(tmp_path):
    p = _sweep(
        tmp_path,
        f"base: {TINY}\naxes:\n"
        "  sim.domain: [[[-1, -1, 0], [1, 1, 1]]]\n"
        "  scene.crop: [[0, 1, 0, 1, 0, 1]]\n"
        "  sim.frames: [0]\n",
    )
    with pytest.raises(UserInputError, match=r"axes.sim.frames: value 0"):
        load_sweep(p)


def test_bad_base_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sim: {grids: 3}\n")
    p = _sweep(tmp_path, "base: bad.yaml\naxes: {optimize.seed: [0, 1]}\n")
    assert main(["batch", str(p)]) == 2
    err = _one_line_error(capsys)
    assert "base bad.yaml" in err and "sim.grids" in err


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("base: nope.yaml\n", "base: run config 'nope.yaml' not found"),
        (f"base: {TINY}\naxis: {{optimize.seed: [0]}}\n", "axis: unknown key"),
        (
            f"base: {TINY}\naxes: {{optimize.seed: 3}}\n",
            "axes.optimize.seed: expected a non-empty list",
        ),
        (
            f"base: {TINY}\naxes: {{optimize.seed: []}}\n",
            "axes.optimize.seed: expected a non-empty list",
        ),
        (f"base: {TINY}\naxes: {{optimize.seed: [1, 1]}}\n", "value 1 appears twice"),
        (f"base: {TINY}\naxes: {{sim.domain: [null]}}\n", "null is not supported"),
        (f"base: {TINY}\naxes: {{'sim..x': [1]}}\n", "not a dotted config key"),
        (f"base: {TINY}\naxes: {{sim: [{{grid: 8}}], sim.frames: [2]}}\n", "overlap"),
        (
            f"base: {TINY}\naxes: {{optimize.seed: [0, 1], sim.frames: [2, 3, 4]}}\n"
            "zip: [[optimize.seed, sim.frames]]\n",
            "zip[0]: zipped axes need the same number of values",
        ),
        (
            f"base: {TINY}\naxes: {{optimize.seed: [0, 1]}}\nzip: [[optimize.seed, prompt]]\n",
            'zip[0]: "prompt" is not an axis',
        ),
        (f"base: {TINY}\nname: 'a b'\n", "name: expected a simple name"),
        ("- 1\n", "expected a YAML mapping"),
    ],
)
def test_bad_sweep_file(tmp_path, capsys, text, expect):
    p = _sweep(tmp_path, text)
    assert main(["batch", str(p), "--dry-run"]) == 2
    err = _one_line_error(capsys)
    assert expect in err and "sweep.yaml" in err


@pytest.mark.parametrize(
    ("flags", "expect"),
    [
        (["--workers", "0"], "--workers"),
        (["--retries", "-1"], "--retries"),
        (["--threads", "0"], "--threads"),
        (["--address", "127.0.0.1:6379"], "--address: only with --executor ray"),
    ],
)
def test_bad_flags(tmp_path, capsys, flags, expect):
    p = _sweep(tmp_path, f"base: {TINY}\naxes: {{optimize.seed: [0]}}\n")
    assert main(["batch", str(p), *flags]) == 2
    assert expect in _one_line_error(capsys)


def test_dry_run_lists_jobs_and_dirs_and_writes_nothing(tmp_path, capsys):
    p = _sweep(tmp_path, f"base: {TINY}\naxes: {{optimize.seed: [0, 1], sim.frames: [2, 3]}}\n")
    out = tmp_path / "out"
    assert main(["batch", str(p), "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    sw = load_sweep(p, out)
    assert "4 jobs" in text
    for j in sw.jobs:
        line = next(ln for ln in text.splitlines() if j.id in ln)
        assert str(sw.job_dir(j)) in line and line.split()[0] == "run"
        assert f"optimize.seed={json.dumps(j.values['optimize.seed'])}" in line
    assert not out.exists()
    assert [pl.action for pl in plan_jobs(sw)] == ["run"] * 4


def test_example_sweep_validates():
    example = Path(__file__).parents[2] / "examples" / "sweeps" / "sweep_demo.yaml"
    sw = load_sweep(example)
    assert len(sw.jobs) == 6 and sw.out == Path("runs") / "sweep_demo"
    assert {j.config.scene.source for j in sw.jobs} == {"builtin:bird"}
    assert len({j.id for j in sw.jobs}) == 6


def test_default_name_is_the_folder_safe_file_stem(tmp_path):
    p = _sweep(tmp_path, f"base: {TINY}\n", "my sweep.yaml")
    sw = load_sweep(p)
    assert sw.name == "my-sweep" and sw.out == Path("runs") / "my-sweep"
    assert len(sw.jobs) == 1  # no axes: the base alone
