"""``motionphysics view`` in a real browser: headless Chromium draws the run's splats.

The viewer runs as the user runs it (a subprocess of the CLI on a free port); the
page is loaded in Debian's Chromium with software WebGL; the timeline is moved with
the keyboard, as a person would. Where the object must be on the screen is computed
independently, by projecting the served splat centres through the start camera
(run.yaml's camera) onto the browser's viewport.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from chromium_cdp import Browser, find_chromium, free_port  # noqa: E402
from tests.conftest import restore_sigint  # noqa: E402

pytestmark = pytest.mark.skipif(
    find_chromium() is None,
    reason="chromium is not installed (Debian: apt-get install chromium; .ci/run installs it as root)",
)

WINDOW = (1280, 720)  # the browser's; the canvas is narrower (the panel is docked beside it)


def _start_view(run_dir: Path, port: int, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "motionphysics.cli",
            "view",
            str(run_dir),
            "--port",
            str(port),
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=restore_sigint,
    )
    deadline = time.monotonic() + 120
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if f"http://127.0.0.1:{port}" in line:
            return proc
    proc.kill()
    out, err = proc.communicate(timeout=10)
    raise AssertionError(f"view did not print its URL:\n{''.join(lines)}{out}\n{err}")


def _project(points: np.ndarray, view: dict, W: int, H: int) -> np.ndarray:
    """World points [M, 3] -> canvas pixels [M, 2] through the start camera (vertical fov)."""
    pos, look, up = (np.asarray(view[k], float) for k in ("position", "look_at", "up"))
    fwd = (look - pos) / np.linalg.norm(look - pos)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    pc = (points - pos) @ np.stack([right, down, fwd]).T
    from motionphysics.viewer.server import Viewer

    f = 0.5 * H / math.tan(0.5 * Viewer.client_fov(view, W, H))
    return np.stack([f * pc[:, 0] / pc[:, 2] + W / 2, f * pc[:, 1] / pc[:, 2] + H / 2], -1)


def _object_mask(uv: np.ndarray, grow: int, W: int, H: int) -> np.ndarray:
    """Pixels within ``grow`` of a projected splat centre, [H, W] bool."""
    mask = np.zeros((H, W), bool)
    ij = np.rint(uv).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    mask[ij[ok, 1], ij[ok, 0]] = True
    from scipy.ndimage import binary_dilation

    return binary_dilation(mask, iterations=grow) if grow else mask


def _press(b: Browser, key: str, code: int) -> None:
    for kind in ("keyDown", "keyUp"):
        b.send(
            "Input.dispatchKeyEvent",
            {"type": kind, "key": key, "code": key, "windowsVirtualKeyCode": code},
        )


def _object_drawn(img: np.ndarray, frame, view) -> tuple[float, float]:
    """(share of the object's pixels showing its colour, share of pixels far from it that do)."""
    H, W = img.shape[:2]
    uv = _project(frame.means.astype(np.float64), view, W, H)
    core = _object_mask(uv, 2, W, H)
    far = ~_object_mask(uv, 40, W, H)
    core[:160, :330] = far[:160, :330] = False  # viser's "software WebGL" notice
    assert core.sum() > 2000, "the object should cover a good part of the view"
    colour = np.median(frame.colors, axis=0) * 255.0
    near = np.linalg.norm(img.astype(float) - colour, axis=-1) < 45.0
    return float(near[core].mean()), float(near[far].mean())


def _wait_for_object(b: Browser, frame, view, W: int, H: int, timeout: float = 120.0):
    """Screenshot [H, W, 3] once the object is drawn where it projects and the picture is still.

    Where the object projects, the page must show its colour (>= 60 % of those pixels);
    away from it, almost never (< 1 %). The splats arrive over the websocket and fade in,
    so this polls (software WebGL on a loaded machine can take a while).
    """
    deadline = time.monotonic() + timeout
    prev, last = None, None
    while True:
        img = b.screenshot()[:H, :W]
        last = _object_drawn(img, frame, view)
        still = prev is not None and np.abs(img.astype(int) - prev.astype(int)).max() <= 8
        if last[0] > 0.6 and last[1] < 0.01 and still:
            return img
        if time.monotonic() > deadline:
            raise AssertionError(
                f"object of frame {frame.index} not drawn where it projects: "
                f"{last[0]:.2f} of its pixels show its colour (want > 0.6), "
                f"{last[1]:.3f} of the pixels far from it do (want < 0.01)"
            )
        prev = img
        time.sleep(1.0)


def test_view_draws_splats_and_frames_differ(tiny_run, tmp_path):
    from motionphysics.viewer.frames import FrameSource
    from motionphysics.viewer.rundata import load_run
    from motionphysics.viewer.server import _camera_view

    run = load_run(tiny_run)
    view = _camera_view(run.config)
    source = FrameSource(run, view["camera"])
    last = run.num_frames - 1
    port = free_port()
    proc = _start_view(tiny_run, port, "--frame", "0")
    try:
        with Browser(*WINDOW) as b:
            b.goto(f"http://127.0.0.1:{port}/")
            b.wait_for("document.querySelector('canvas') !== null", 60)
            b.wait_for("document.querySelector('[role=slider]') !== null", 60)
            rect = b.evaluate(
                "(() => { const r = document.querySelector('canvas').getBoundingClientRect();"
                " return [r.x, r.y, r.width, r.height]; })()"
            )
            assert rect[0] == 0 and rect[1] == 0 and rect[2] > 0.5 * WINDOW[0], rect
            W, H = int(rect[2]), int(rect[3])
            first = _wait_for_object(b, source.frame(0), view, W, H)
            # Move the timeline to the last frame with the keyboard, as a person would.
            b.evaluate("document.querySelector('[role=slider]').focus()")
            _press(b, "End", 35)
            b.wait_for(
                f"document.querySelector('[role=slider]').getAttribute('aria-valuenow') == '{last}'",
                30,
            )
            second = _wait_for_object(b, source.frame(last), view, W, H)
            changed = np.abs(first.astype(int) - second.astype(int)).max(-1) > 40
            assert changed.mean() > 0.02, changed.mean()
            (tmp_path / "shots").mkdir()
            from PIL import Image

            Image.fromarray(first).save(tmp_path / "shots" / "frame0.png")
            Image.fromarray(second).save(tmp_path / "shots" / f"frame{last}.png")
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode in (0, 130), err
    assert "Traceback" not in err, err
