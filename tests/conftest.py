"""Shared test fixtures: the tiny run config the pipeline-level suites build, its
prepared assembly, and the ONE central finite-difference check of torch gradients.

Everything here is small enough for the default suite (a 0.3 m sphere of ~150
particles on a 10-cell grid, 3 frames at a 16 px camera); tests that need another
size copy :func:`tiny_config_data` and edit it.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

TINY_CONFIG = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.25],
        "max_particles": 150,
    },
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3},
    "sim": {"grid": 10, "frames": 3, "frame_dt": 0.02, "substeps": 12},
    "boundary_conditions": [
        {
            "type": "surface_collider",
            "point": [0, 0, 0],
            "normal": [0, 0, 1],
            "mode": "frictional",
            "friction": 0.3,
        },
        {"type": "bounding_box"},
    ],
    "camera": {"width": 16, "height": 16},
}


def tiny_config_data(**sections) -> dict:
    """A deep copy of :data:`TINY_CONFIG` with top-level ``sections`` replaced."""
    data = copy.deepcopy(TINY_CONFIG)
    data.update(copy.deepcopy(sections))
    return data


@pytest.fixture
def tiny_config() -> Callable[..., object]:
    """``tiny_config(**sections) -> RunConfig`` of the tiny scene."""
    from motionphysics.config import config_from_dict

    return lambda **sections: config_from_dict(tiny_config_data(**sections), "tiny")


@pytest.fixture(scope="session")
def tiny_assembly():
    """The assembly (scene, camera, material, simulation context) of the tiny config."""
    from motionphysics.assembly import assemble
    from motionphysics.config import config_from_dict

    return assemble(
        config_from_dict(tiny_config_data(), "tiny"), estimate=False, reference_image=False
    )


def central_differences(fn, leaves: Sequence, k: int, h: float):
    """Central difference of scalar ``fn(*leaves)`` w.r.t. every entry of ``leaves[k]``."""
    import torch

    leaf = leaves[k]
    flat = leaf.detach().clone().reshape(-1)
    fd = torch.empty_like(flat)
    for i in range(flat.numel()):
        vals = []
        for sgn in (1.0, -1.0):
            x = flat.clone()
            x[i] += sgn * h
            args = [t.detach() for t in leaves]
            args[k] = x.reshape(leaf.shape)
            with torch.no_grad():
                vals.append(fn(*args).item())
        fd[i] = (vals[0] - vals[1]) / (2 * h)
    return fd


def _fd_check(fn, leaves, h: float = 1e-6, rtol: float = 1e-6) -> None:
    """Autograd of scalar ``fn(*leaves)`` against central differences in every entry.

    Meant for float64 leaves: with h = 1e-6 the truncation error is ~h^2 f''' ~1e-12
    and the rounding error ~1e-16 / h = 1e-10, both far below ``rtol`` (1e-6) of the
    largest derivative (plus 1e-9 absolute). Also asserts that the function really
    depends on each leaf (a zero derivative everywhere would pass trivially).
    """
    leaves = [t.detach().clone().requires_grad_() for t in leaves]
    fn(*leaves).backward()
    for k, leaf in enumerate(leaves):
        fd = central_differences(fn, leaves, k, h)
        ag = leaf.grad.reshape(-1)
        scale = max(fd.abs().max().item(), 1e-12)
        assert (ag - fd).abs().max().item() <= rtol * scale + 1e-9, (k, ag, fd)
        assert fd.abs().max() > 0  # the input really influences the value


@pytest.fixture
def fd_check():
    """``fd_check(fn, leaves, h=1e-6, rtol=1e-6)``: see :func:`_fd_check`."""
    return _fd_check


def restore_sigint() -> None:
    """``preexec_fn`` for a child process a test interrupts with SIGINT. A shell without
    job control starts background jobs with SIGINT ignored, and a Python child that
    starts with it ignored never raises KeyboardInterrupt, so the test would see exit 0
    or a hang instead of the behaviour under test."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


@dataclass
class CliRun:
    """A run a test made through the command line with a config file it wrote."""

    rc: int
    out: str
    err: str
    dir: Path

    @property
    def params(self) -> dict:
        return json.loads((self.dir / "params.json").read_text())

    def trajectory(self) -> dict:
        import numpy as np

        return dict(np.load(self.dir / "trajectory.npz"))


@pytest.fixture
def cli_run(tmp_path, capsys) -> Callable[..., CliRun]:
    """``cli_run(data, name, command="simulate", *flags)``: write ``data`` as NAME.yaml in
    the test's folder, run ``motionphysics COMMAND NAME.yaml --out NAME FLAGS`` as a user
    would, and return its exit status, stdout, stderr and run folder."""
    import yaml

    from motionphysics.cli import main

    def run(data: dict, name: str, command: str = "simulate", *flags: str) -> CliRun:
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        capsys.readouterr()
        rc = main([command, str(path), "--out", str(tmp_path / name), *flags])
        io = capsys.readouterr()
        return CliRun(rc, io.out, io.err, tmp_path / name)

    return run
