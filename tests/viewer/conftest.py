"""Fixtures of the viewer tests: tiny run directories made with the real CLI."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from viewer_runs import DATA, make_run  # noqa: E402


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """A 0.3 m ball thrown sideways onto the ground: 8 frames, ~4k splats, ~1.2k particles."""
    return make_run(DATA / "view_tiny.yaml", tmp_path_factory.mktemp("view") / "run")
