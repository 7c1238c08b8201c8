"""A file system that fills up while a run directory is written.

The run directory lives on a 2 MiB tmpfs (mounted here when the machine lets root do
so); when a chosen stage begins, a ballast file takes every free block, as another
process filling the disk would. The run must end with status 1 and ONE line naming
the file and the full disk (``errors.OutputError``), every file written before the
disk filled must be byte-for-byte what it was, no temporary may be left, and once the
ballast is gone ``--resume`` finishes the run.

Where mounting is not permitted the same check runs with an injected ENOSPC at the
writer (``os.fsync`` of every atomic write fails from that stage on), which covers the
run directory's own writes but not those of library writers (ffmpeg, matplotlib).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import subprocess
import uuid
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml
from test_resume import TINY

from motionphysics.cli import main
from motionphysics.io.writer import RunWriter

TMPFS_SIZE = "2m"


def _digests(run_dir: Path) -> dict[str, str]:
    return {
        str(p.relative_to(run_dir)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(run_dir.rglob("*"))
        if p.is_file()
    }


def _fill(folder: Path) -> Path:
    """Take every free block of the file system of ``folder`` (returns the ballast)."""
    ballast = folder / f"ballast-{uuid.uuid4().hex}"
    with open(ballast, "wb", buffering=0) as f:  # unbuffered: nothing left to flush
        for chunk in (1 << 16, 4096, 512, 1):
            block = b"\0" * chunk
            try:
                while True:
                    f.write(block)
            except OSError as err:
                assert err.errno == errno.ENOSPC, err
    return ballast


@pytest.fixture
def tmpfs(tmp_path):
    """A fresh size-limited tmpfs, or a skip when this machine does not allow mounting."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={TMPFS_SIZE}", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()}); the injected case runs")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill_at(monkeypatch, stage: str, action):
    """Run ``action()`` just inside stage ``stage`` (after the stage's own params.json)."""
    real = RunWriter.stage
    state: dict[str, object] = {}

    @contextmanager
    def stage_then_fill(self, name, total=None):
        with real(self, name, total) as st:
            if name == stage and "snapshot" not in state:
                state["snapshot"] = _digests(self.path)
                state["ballast"] = action(self.path)
            yield st

    monkeypatch.setattr(RunWriter, "stage", stage_then_fill)
    return state


def _check_failed_run(run: Path, state, capsys, stage: str) -> None:
    # (the failure's one line; the warnings about the physics of the tiny scene before it
    # -- a 0.3 m ball on an 8-cell grid -- are not what is checked)
    err = [
        ln
        for ln in capsys.readouterr().err.splitlines()
        if ln.strip() and not ln.startswith("warning:")
    ]
    assert len(err) == 1, err
    line = err[0]
    assert "no space left" in line and str(run) in line and "Traceback" not in line
    snap = state["snapshot"]
    now = _digests(run)
    for name, digest in snap.items():
        assert now.get(name) == digest, f"{name} changed or vanished after the disk filled"
    extra = {n for n in now if n not in snap and not n.startswith("ballast")}
    assert not extra, f"files appeared on a full disk: {extra}"
    assert not [n for n in os.listdir(run) if n.startswith(".")], "temporaries left behind"
    params = json.loads((run / "params.json").read_text())
    assert params["partial"] is True and params["stage"] == stage
    yaml.safe_load((run / "run.yaml").read_text())


@pytest.mark.parametrize(
    "stage",
    [
        "write outputs",
        pytest.param("render", marks=pytest.mark.slow),
        pytest.param("simulate", marks=pytest.mark.slow),
    ],
)
def test_full_tmpfs_keeps_the_files_and_ends_in_one_line(
    tmpfs, tmp_path, capsys, monkeypatch, stage
):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    run = tmpfs / "run"
    state = _fill_at(monkeypatch, stage, lambda path: _fill(path.parent))
    rc = main(["--quiet", "simulate", str(cfg), "--out", str(run)])
    assert rc == 1
    _check_failed_run(run, state, capsys, stage)
    # space again: the same run resumes and finishes
    Path(state["ballast"]).unlink()
    monkeypatch.undo()
    assert main(["--quiet", "simulate", str(cfg), "--out", str(run), "--resume"]) == 0
    assert json.loads((run / "params.json").read_text())["partial"] is False


def test_injected_enospc_at_the_writer(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    run = tmp_path / "run"

    def inject(path):
        def no_space(fd):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(os, "fsync", no_space)
        return None

    state = _fill_at(monkeypatch, "write outputs", inject)
    rc = main(["--quiet", "simulate", str(cfg), "--out", str(run)])
    assert rc == 1
    _check_failed_run(run, state, capsys, "write outputs")


# -- the pieces, without a simulation ---------------------------------------------------
def test_atomic_writes_on_a_full_tmpfs_keep_the_old_file(tmpfs):
    from motionphysics.errors import OutputError
    from motionphysics.io.rundir import RunDirectory

    rd = RunDirectory(tmpfs / "run")
    rd.write_json("params.json", {"partial": True, "stage": "start"})
    old = (tmpfs / "run" / "params.json").read_bytes()
    ballast = _fill(tmpfs)
    for write in (
        lambda: rd.write_json("params.json", {"partial": True, "big": "x" * 100_000}),
        lambda: rd.append_jsonl("log.jsonl", {"iteration": 0, "pad": "y" * 100_000}),
    ):
        with pytest.raises(OutputError, match="no space left") as info:
            write()
        assert "\n" not in str(info.value) and str(tmpfs / "run") in str(info.value)
    assert (tmpfs / "run" / "params.json").read_bytes() == old
    assert not [n for n in os.listdir(tmpfs / "run") if n.startswith(".")]
    ballast.unlink()


def test_a_torn_video_never_replaces_video_mp4(tmp_path):
    import numpy as np

    from motionphysics.errors import OutputError
    from motionphysics.io.video import write_video
    from motionphysics.io.writer import _check_mp4

    rng = np.random.default_rng(0)
    good = write_video(rng.integers(0, 255, (6, 16, 16, 3), dtype=np.uint8), tmp_path / "a.mp4", 10)
    _check_mp4(good)  # a whole file passes
    data = good.read_bytes()
    for cut in (0, 8, len(data) // 2, len(data) - 1):
        torn = tmp_path / f"torn{cut}.mp4"
        torn.write_bytes(data[:cut])
        with pytest.raises(OSError, match="incomplete"):
            _check_mp4(torn)
    # through the writer: the previous video.mp4 stays, one line names the file
    from motionphysics.io.writer import RunWriter

    w = RunWriter(tmp_path / "run", command="simulate")
    w.rd.write_bytes("video.mp4", data)
    import motionphysics.io.video as video

    real = video.write_video

    def torn_writer(frames, path, fps):
        real(frames, path, fps)
        Path(path).write_bytes(data[: len(data) // 3])  # what ffmpeg leaves on a full disk

    try:
        video.write_video = torn_writer
        with pytest.raises(OutputError, match="video.mp4") as info:
            w.write_video(rng.integers(0, 255, (6, 16, 16, 3), dtype=np.uint8), 0.1)
    finally:
        video.write_video = real
    assert "\n" not in str(info.value)
    assert (tmp_path / "run" / "video.mp4").read_bytes() == data
    assert not [n for n in os.listdir(tmp_path / "run") if n.startswith(".")]
