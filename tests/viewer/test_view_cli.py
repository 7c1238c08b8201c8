"""``motionphysics view``: one-line errors (status 2) for non-runs, busy ports, bad frames."""

from __future__ import annotations

import shutil
import socket
import sys
from pathlib import Path

import numpy as np

from motionphysics.cli import main

sys.path.insert(0, str(Path(__file__).parent))
from chromium_cdp import free_port  # noqa: E402
from tests.conftest import restore_sigint  # noqa: E402


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    return err


def test_not_a_run_names_missing_files(tmp_path, capsys):
    (tmp_path / "run.yaml").write_text("prompt: x\n")
    assert main(["view", str(tmp_path), "--port", str(free_port())]) == 2
    err = _one_line_error(capsys)
    assert str(tmp_path) in err
    assert "params.json" in err and "trajectory.npz" in err and "scene.ply" in err
    assert main(["view", str(tmp_path / "nope")]) == 2
    assert "no such directory" in _one_line_error(capsys)


def test_missing_trajectory_array_is_named(tiny_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    with np.load(run / "trajectory.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "splat_parent"}
    np.savez(run / "trajectory.npz", **arrays)
    assert main(["view", str(run), "--port", str(free_port())]) == 2
    err = _one_line_error(capsys)
    assert "trajectory.npz" in err and "splat_parent" in err


def test_port_in_use_is_exit_2(tiny_run, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert main(["view", str(tiny_run), "--port", str(port)]) == 2
    err = _one_line_error(capsys)
    assert f"port {port}" in err and "already in use" in err


def test_frame_out_of_range(tiny_run, capsys):
    assert main(["view", str(tiny_run), "--port", str(free_port()), "--frame", "99"]) == 2
    err = _one_line_error(capsys)
    assert "--frame" in err and "0..7" in err


def test_sigint_stops_cleanly(tiny_run):
    import os
    import signal
    import subprocess

    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionphysics.cli", "view", str(tiny_run), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=restore_sigint,
    )
    line = ""
    for _ in range(20):
        line = proc.stdout.readline()
        if "http://" in line or not line:
            break
    assert f"http://127.0.0.1:{port}" in line
    # The page is served on the port asked for, on the loopback address only.
    import urllib.request

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
        assert r.status == 200 and b"<html" in r.read().lower()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode in (0, 130)
    assert "Traceback" not in err, err
