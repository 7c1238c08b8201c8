"""The demo's config: packaged copy equals examples/demo.yaml, and it validates."""

from __future__ import annotations

from pathlib import Path

from motionphysics.commands.demo import PACKAGED, demo_config_path
from motionphysics.pipeline import load_run_config

ROOT = Path(__file__).resolve().parents[1]


def test_packaged_copy_is_identical():
    assert PACKAGED.read_text() == (ROOT / "examples" / "demo.yaml").read_text()
    assert demo_config_path().is_file()


def test_demo_config_is_valid_and_estimates_from_the_prompt():
    cfg = load_run_config(PACKAGED)
    assert cfg.scene.source == "builtin:bird"
    assert cfg.material.class_ is None  # embedded defaults: the material comes from the prompt
    assert cfg.optimize.prior == "none"
    assert "radius" not in cfg.camera.model_fields_set  # auto-framed
