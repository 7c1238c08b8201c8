"""estimate(): input checks, the median baseline, MaterialEstimate serialisation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from motionphysics.errors import UserInputError
from motionphysics.init import EstimateOptions, MaterialEstimate, estimate
from motionphysics.init.baselines import median_params, median_value
from motionphysics.init.estimate import check_prompt, load_image_png
from motionphysics.materials.catalog import DENSITY, Clamp, materials


@pytest.mark.parametrize(
    "prompt, match",
    [
        ("", "empty"),
        ("   \n ", "empty"),
        ("x" * 100_000, "too long"),
        (None, "expected text"),
        ("bad\x00byte", "control characters"),
        ("caf\udce9", "UTF-8"),
    ],
)
def test_bad_prompts(prompt, match):
    with pytest.raises(UserInputError, match=match):
        check_prompt(prompt)


def test_bad_backend_and_image(tmp_path):
    with pytest.raises(UserInputError, match="--backend"):
        estimate("An axe.", backend="oracle")
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image at all")
    with pytest.raises(UserInputError, match="not a readable image"):
        estimate("An axe.", image=junk, backend="median", options=EstimateOptions(cls="metal"))
    with pytest.raises(UserInputError, match="file not found"):
        load_image_png(tmp_path / "missing.png")
    with pytest.raises(UserInputError, match="image array"):
        load_image_png(np.zeros((4, 4)))


def test_image_inputs_become_png(tmp_path):
    arr = np.zeros((2000, 10, 3), dtype=np.float32)
    arr[..., 0] = 1.0
    png = load_image_png(arr)
    from io import BytesIO

    from PIL import Image

    img = Image.open(BytesIO(png))
    assert img.format == "PNG" and max(img.size) == 1024  # downscaled
    assert img.getpixel((0, 0)) == (255, 0, 0)
    assert load_image_png(png)[:8] == b"\x89PNG\r\n\x1a\n"


def test_median_backend_arithmetic_and_geometric():
    est = estimate(
        "whatever", backend="median", options=EstimateOptions(cls="Elastic", ranges="paper")
    )
    assert est.cls == "elastic" and est.backend == "median" and est.ranges == "paper"
    # the paper's ablation value: E = 2e11 Pa for the paper's elastic range 1e7 - 4e11
    assert est.values["E"] == pytest.approx(2.00005e11, rel=1e-12)
    assert est.values["nu"] == pytest.approx(0.3)
    assert est.density == pytest.approx((10 + 2.3e4) / 2)
    geo = median_params("elastic", "geometric", "paper")
    assert geo.values["E"] == pytest.approx(math.sqrt(1e7 * 4e11))
    assert geo.values["nu"] == pytest.approx(0.3)  # linear parameters: midpoint either way
    # the extended table (the default) reaches down to gels: 1e3 - 4e11
    ext = estimate("whatever", backend="median", options=EstimateOptions(cls="elastic"))
    assert ext.ranges == "extended"
    assert ext.values["E"] == pytest.approx((1e3 + 4e11) / 2, rel=1e-12)
    assert median_params("elastic", "geometric").values["E"] == pytest.approx(math.sqrt(1e3 * 4e11))
    for table in ("extended", "paper"):
        for cls, mc in materials(table).items():
            for kind in ("arithmetic", "geometric"):
                p = median_params(cls, kind, table)
                assert DENSITY.contains(p.density)
                for ps in mc.params:
                    assert ps.contains(p.values[ps.name])
    with pytest.raises(ValueError):
        median_value(DENSITY, "mode")


def test_material_estimate_json_schema():
    est = MaterialEstimate(
        "metal",
        7850.0,
        {"E": 2e11, "nu": 0.3, "tau_Y": 2.5e8},
        "llm",
        clamped=[Clamp("E", 1e12, 4e11, "clamped", "llm")],
        raw_answer="{}",
        prompt="An axe.",
    )
    d = json.loads(est.to_json())
    assert d["material"] == {
        "class": "metal",
        "density": 7850.0,
        "E": 2e11,
        "nu": 0.3,
        "tau_Y": 2.5e8,
    }
    assert d["backend"] == "llm" and d["raw_answer"] == "{}"
    assert d["clamped"] == [
        {"field": "E", "original": 1e12, "clamped": 4e11, "kind": "clamped", "source": "llm"}
    ]
    assert est.params.values["E"] == 2e11 and est.params.cls == "metal"
