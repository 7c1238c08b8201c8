"""A mesh written in millimetres is told its size as read, through ``motionphysics simulate
CONFIG``: an STL of a 40 cm crate exported in mm is a 400 m crate to a tool whose world is
in metres. The same crate scaled to metres says nothing."""

from __future__ import annotations

import pytest

WOOD = {"class": "elastic", "density": 600.0, "E": 1.0e7, "nu": 0.3}


@pytest.mark.parametrize("scale, told", [(1.0, True), (0.001, False)])
def test_a_crate_in_millimetres_is_told_its_size(tmp_path, cli_run, scale, told):
    trimesh = pytest.importorskip("trimesh")
    stl = tmp_path / "crate_mm.stl"
    trimesh.creation.box(extents=[400.0, 300.0, 250.0]).export(stl)
    data = {
        "scene": {"source": str(stl), "scale": scale, "max_particles": 600},
        "prompt": "A wooden crate rests on the floor.",
        "material": WOOD,
        "sim": {"grid": 12, "frames": 1, "frame_dt": 0.01, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }
    run = cli_run(data, "crate")
    assert run.rc == 0
    lines = [s for s in run.err.splitlines() if "m across" in s]
    assert bool(lines) == told, lines
    capture = run.params["scene"].get("capture")
    if told:
        assert "the body simulated is 400 m across (the file's units read as metres" in lines[0]
        assert capture == lines[0].removeprefix("warning: ")
    else:
        assert capture is None
