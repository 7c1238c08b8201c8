"""``render`` output locations: every unwritable or invalid --out is one line, no traceback,
nothing created, nothing half-written left behind."""

from __future__ import annotations

import errno
import subprocess
import sys

import pytest

from motionphysics import cli
from motionphysics.errors import OutputError, UserInputError
from motionphysics.io import paths


@pytest.fixture
def run_cli(monkeypatch):
    monkeypatch.setattr(cli, "COMMANDS", ["render"])
    return cli.main


SMALL = ["--width", "32", "--height", "32"]


def test_missing_parent_is_refused_and_never_created(run_cli, tmp_path, capsys):
    out = tmp_path / "nonexist" / "deeper" / "x.png"
    assert run_cli(["render", "builtin:sphere", "--out", str(out), *SMALL]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "does not exist" in err and str(out) in err
    assert not (tmp_path / "nonexist").exists()


def test_folder_as_output_is_refused(run_cli, tmp_path, capsys):
    d = tmp_path / "d.png"
    d.mkdir()
    assert run_cli(["render", "builtin:sphere", "--out", str(d), *SMALL]) == 2
    assert "is a folder" in capsys.readouterr().err


@pytest.mark.parametrize("code", [errno.EACCES, errno.EROFS])
def test_unwritable_folder_is_one_line_status_2(run_cli, tmp_path, capsys, monkeypatch, code):
    # As root chmod does not stop writes; fail the probe the way the kernel would.
    def refuse(*a, **k):
        raise OSError(code, "denied")

    monkeypatch.setattr(paths.tempfile, "NamedTemporaryFile", refuse)
    out = tmp_path / "x.png"
    assert run_cli(["render", "builtin:sphere", "--out", str(out), *SMALL]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot write in" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_real_read_only_location(tmp_path):
    # /sys is read-only for everyone (root included) on Linux.
    if sys.platform != "linux":
        pytest.skip("Linux only")
    r = subprocess.run(
        [sys.executable, "-m", "motionphysics", "render", "builtin:sphere", "--out", "/sys/x.png"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "/sys/x.png" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "exc, status, words",
    [
        (BrokenPipeError(errno.EPIPE, "Broken pipe"), 1, "broken pipe"),
        (OSError(errno.ENOSPC, "No space left on device"), 1, "no space left"),
        (PermissionError(errno.EACCES, "Permission denied"), 2, "permission denied"),
        (
            OSError("[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\n/usr/bin/ffmpeg -y ..."),
            1,
            "broken pipe",
        ),
    ],
)
def test_write_failures_are_one_line_and_leave_nothing(
    run_cli, tmp_path, capsys, monkeypatch, exc, status, words
):
    import motionphysics.io.video as video

    out = tmp_path / "orbit.mp4"
    partial = tmp_path / ".orbit.partial.mp4"

    def broken(frames, path, fps=25.0):
        partial.write_bytes(b"half a video")
        raise exc

    monkeypatch.setattr(video, "write_video", broken)
    rc = run_cli(
        ["render", "builtin:sphere", "--orbit", "--frames", "2", "--out", str(out), *SMALL]
    )
    err = capsys.readouterr().err.strip()
    assert rc == status and len(err.splitlines()) == 1, err
    assert words in err.lower() and "FFMPEG COMMAND" not in err
    assert not partial.exists() and not out.exists()


def test_writing_context_maps_errors():
    with pytest.raises(UserInputError), paths.writing("x.png"):
        raise PermissionError(errno.EACCES, "no")
    with pytest.raises(OutputError), paths.writing("x.png"):
        raise OSError(errno.EIO, "io")
