"""A large run (100k splats x 100 frames) is streamed: the viewer never holds every frame.

Slow (writes a ~0.5 GB trajectory). The viewer runs as a subprocess; its anonymous
(heap) memory is compared with the same viewer's on the tiny run: the trajectory is
memory-mapped (file-backed pages), and only the current frame and a small cache are
ever computed, so the heap grows by far less than the trajectory's size.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from chromium_cdp import free_port  # noqa: E402
from tests.conftest import restore_sigint  # noqa: E402

pytestmark = pytest.mark.slow

N = P = 100_000
T = 100


def _rss_anon_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no RssAnon in /proc status")


def _serve(run_dir: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionphysics.cli", "view", str(run_dir), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=restore_sigint,
    )
    lines = []
    while True:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "http://" in line:
            return proc, "".join(lines)
    proc.kill()
    raise AssertionError("".join(lines) + proc.stderr.read())


def _stop(proc) -> None:
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode in (0, 130)


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs Linux /proc")
def test_large_run_is_streamed(tiny_run, tmp_path):
    from motionphysics.scene.gaussians import GaussianScene
    from motionphysics.scene.ply import write_ply

    run = tmp_path / "large"
    run.mkdir()
    for f in ("run.yaml", "params.json"):
        shutil.copy(tiny_run / f, run / f)
    rng = np.random.default_rng(0)
    means = (0.1 * rng.normal(size=(N, 3)) + [0.0, 0.0, 0.3]).astype(np.float32)
    write_ply(
        GaussianScene(
            torch.from_numpy(means),
            torch.full((N, 3), -5.0),
            torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(N, 1),
            torch.full((N,), 2.0),
            torch.from_numpy((0.3 * rng.normal(size=(N, 1, 3))).astype(np.float32)),
        ),
        run / "scene.ply",
    )
    x = np.repeat(means[None], T, 0) + (0.01 * np.arange(T, dtype=np.float32))[:, None, None]
    F = np.broadcast_to(np.eye(3, dtype=np.float32), (T, P, 3, 3))
    np.savez(
        run / "trajectory.npz",
        x=x,
        t=0.04 * np.arange(T, dtype=np.float32),
        F=F,
        splat_parent=np.arange(N),
        splat_offset=np.zeros((N, 3), np.float32),
    )
    traj_mb = (x.nbytes + F.nbytes) / 2**20
    del x, F

    proc, out = _serve(tiny_run)
    time.sleep(1.0)
    base = _rss_anon_mb(proc.pid)
    _stop(proc)

    proc, out = _serve(run)
    try:
        assert "large run" in out and "streamed one at a time" in out
        time.sleep(1.0)
        heap = _rss_anon_mb(proc.pid) - base
    finally:
        _stop(proc)
    # One computed frame is ~6 MB; the whole trajectory is ~460 MB.
    assert heap < 0.25 * traj_mb, (heap, traj_mb)
