"""A capture loaded as it is (``scene: {source: capture.ply}``) is told what it was read as,
through ``motionphysics simulate CONFIG``: the shared table capture was simulated as one
57 m jelly with z up, without a word. Judged on stderr and ``params.json`` scene.capture.

* its header's "Vertical axis: y" against the z up it is simulated with (scene.up left out);
* its floaters (2 % of the splats spread the box of all to 6x the rest): the warning's own
  ``scene.crop`` discards them, and the line goes;
* its size as read (4.7 m: a capture's units are not metres);
* none of these for a region run, a scaled object capture, or a given ``scene.up``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from motionphysics.scene.capture_notes import header_up_axis

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
TABLE, DONUT = REAL / "yashica_t4_table.ply", REAL / "donut.ply"
needs_captures = pytest.mark.skipif(
    not (TABLE.is_file() and DONUT.is_file()), reason="real captures in shared/data/real absent"
)
JELLY = {"class": "elastic", "density": 1050.0, "E": 5000.0, "nu": 0.45}


def _simulate(cli_run, scene: dict, name: str):
    data = {
        "scene": {"max_particles": 1500, **scene},
        "prompt": "The camera is made of jelly and wobbles.",
        "material": JELLY,
        "sim": {"grid": 16, "frames": 1, "frame_dt": 0.01, "substeps": "auto"},
        "camera": {"width": 16, "height": 16},
    }
    run = cli_run(data, name)
    assert run.rc == 0
    lines = [s for s in run.err.splitlines() if s.startswith("warning: scene: ")]
    return lines, run.params["scene"].get("capture")


@needs_captures
def test_the_table_capture_as_it_is_is_told_its_axis_floaters_and_size(cli_run):
    lines, recorded = _simulate(cli_run, {"source": str(TABLE)}, "plain")
    assert len(lines) == 3, lines
    axis, floaters, size = lines
    assert "header says 'Vertical axis: y'" in axis and "`scene.up: y` or `-y`" in axis
    m = re.search(r"(\d+) of (\d+) splats \(([\d.]+) %\) lie far from the rest", floaters)
    assert m and 0 < int(m.group(1)) < 0.05 * int(m.group(2))
    spans = re.search(r"span ([\d.]+) m, (\d+)x the ([\d.]+) m", floaters)
    assert float(spans.group(1)) > 3 * float(spans.group(3))
    assert re.search(r"body simulated is 4\.\d+ m across", size)
    assert recorded == "\n".join(s[len("warning: ") :] for s in lines)

    # the crop the warning gives, as the user would paste it: the floaters' line goes
    crop = ast.literal_eval(re.search(r"`scene\.crop: (\[[^\]]+\])`", floaters).group(1))
    lines, _ = _simulate(cli_run, {"source": str(TABLE), "crop": crop}, "cropped")
    assert len(lines) == 2 and not any("floaters" in s for s in lines), lines
    # the axis the header names, and a scale: nothing left to say
    scene = {"source": str(TABLE), "up": "-y", "scale": 0.04}
    lines, recorded = _simulate(cli_run, scene, "scaled")
    assert not any("header says" in s or "m across" in s for s in lines), lines


@needs_captures
def test_a_region_run_and_a_small_object_capture_are_told_nothing(cli_run):
    region = {
        "source": str(TABLE),
        "up": [0.03413075, -0.75571442, -0.65401132],
        "scale": 0.04,
        "translate": [0.0172, -0.0344, 0.1491],
        "region": {"box": [[-0.062, -0.031, 0.0012], [0.062, 0.031, 0.07]]},
    }
    assert _simulate(cli_run, region, "region") == ([], None)
    assert _simulate(cli_run, {"source": str(DONUT)}, "donut") == ([], None)


@pytest.mark.parametrize(
    "comment, want",
    [
        ("Vertical axis: y", "y"),
        ("up_axis = -Y", "-y"),
        ("Up axis: z", "z"),
        ("source sha256 12d644e1a13c", None),
    ],
)
def test_header_up_axis_reads_the_comment_a_capture_tool_writes(tmp_path, comment, want):
    path = tmp_path / "c.ply"
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex 1\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    path.write_bytes(header.encode() + np.zeros(3, np.float32).tobytes())
    got = header_up_axis(str(path))
    assert (got[0] if got else None) == want
    assert header_up_axis("builtin:duck") is None
