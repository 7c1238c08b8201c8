"""Builtin scenes: normalised, deterministic, the promised shapes and colours; the CLI lists them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from motionphysics.cli import main
from motionphysics.errors import UserInputError
from motionphysics.scene import load_scene
from motionphysics.scene.builtin import list_builtins

NAMES = [name for name, _ in list_builtins()]


@pytest.fixture(scope="module")
def scenes():
    return {name: load_scene(f"builtin:{name}") for name in NAMES}


def _extent(s):
    return (s.means.max(0).values - s.means.min(0).values).double().numpy()


def test_required_builtins_exist():
    for name in (
        "sphere",
        "cube",
        "column",
        "torus",
        "rod",
        "bird",
        "duck",
        "bird_textured",
        "bird_plain",
    ):
        assert name in NAMES
    assert all(desc and "\n" not in desc for _, desc in list_builtins())


@pytest.mark.parametrize("name", NAMES)
def test_builtin_is_normalised_and_sane(scenes, name):
    s = scenes[name]
    s.validate(name)
    assert 1000 <= s.num <= 10000
    ext = _extent(s)
    # float32 means of O(1): max extent 1 and bbox centre 0 to ~1 ulp of 1.
    assert abs(ext.max() - 1.0) < 1e-6
    centre = 0.5 * (s.means.max(0).values + s.means.min(0).values)
    assert float(centre.abs().max()) < 1e-6
    np.testing.assert_allclose(s.opacities.numpy(), 0.9, atol=1e-6)
    sc = s.scales
    # Surface splats: flat (thin axis 10x smaller), in-plane size ~ sample spacing (0.2%-5% of size).
    assert float(sc[:, :2].min()) > 2e-3 and float(sc.max()) < 0.05
    np.testing.assert_allclose((sc[:, 2] / sc[:, 0]).numpy(), 0.1, rtol=1e-5)
    assert s.sh_degree == 0


def test_builtins_are_deterministic(scenes):
    again = load_scene("builtin:duck")
    assert torch.equal(again.means, scenes["duck"].means) and torch.equal(
        again.sh, scenes["duck"].sh
    )


def test_shape_proportions(scenes):
    np.testing.assert_allclose(_extent(scenes["column"]), [0.5, 0.5, 1.0], atol=1e-6)
    rod = _extent(scenes["rod"])
    assert rod.argmax() == 0 and rod[1] < 0.2 and rod[2] < 0.2
    torus = scenes["torus"].means.double()
    r_xy = torus[:, :2].norm(dim=1)
    # Ring: no splat near the axis, outer radius 0.5, thickness 0.3 of the diameter.
    assert float(r_xy.min()) > 0.15 and abs(float(r_xy.max()) - 0.5) < 0.01
    sphere = scenes["sphere"].means.double()
    np.testing.assert_allclose(
        sphere.norm(dim=1).numpy(), 0.5, atol=2e-3
    )  # on the ellipsoid exactly (renormalised)


def test_appearance_variants_share_the_shape(scenes):
    bird, tex, plain = scenes["bird"], scenes["bird_textured"], scenes["bird_plain"]
    assert torch.equal(bird.means, tex.means) and torch.equal(bird.means, plain.means)
    plain_cols = plain.base_colors()
    assert float((plain_cols - plain_cols[0]).abs().max()) == 0.0
    # Textured: many distinct colours, with strong local contrast.
    assert len(torch.unique(tex.base_colors(), dim=0)) >= 8
    assert float(tex.base_colors().std(0).mean()) > float(bird.base_colors().std(0).mean()) * 0.8


def test_paper_bird_variants(scenes):
    bird, red, simple = scenes["bird"], scenes["bird_red"], scenes["bird_simple"]
    assert torch.equal(bird.means, red.means)
    body = (bird.base_colors() - torch.tensor([0.22, 0.42, 0.85])).abs().max(dim=1).values < 1e-5
    assert int(body.sum()) > bird.num // 3  # the body is the largest part
    torch.testing.assert_close(
        red.base_colors()[body], torch.tensor([[0.85, 0.2, 0.18]]).expand(int(body.sum()), 3)
    )
    # No tail and no beak: shorter in x than the full bird before normalisation, so after
    # normalisation its y/x aspect is larger, and no beak-yellow remains.
    assert _extent(simple)[1] > _extent(bird)[1] * 1.1
    c = simple.base_colors()
    assert not bool(((c[:, 0] > 0.9) & (c[:, 1] > 0.6) & (c[:, 2] < 0.2)).any())


@pytest.mark.parametrize("name", ["bird", "duck"])
def test_compound_shapes_have_distinct_part_colours(scenes, name):
    cols = torch.unique(scenes[name].base_colors(), dim=0)
    assert len(cols) >= 4  # body, head, beak, wings/tail (and eyes)
    # The beak (orange/yellow) sits at the front (+x).
    s = scenes[name]
    front = s.means[:, 0] > 0.45
    c = s.base_colors()[front]
    assert bool(((c[:, 0] > 0.9) & (c[:, 2] < 0.2) & (c[:, 1] < 0.8)).any())


def test_unknown_builtin_is_a_user_error():
    with pytest.raises(UserInputError) as e:
        load_scene("builtin:unicorn")
    assert "builtin:unicorn" in str(e.value) and "sphere" in str(e.value)


def test_scenes_command_lists_every_builtin(capsys):
    assert main(["scenes"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(NAMES)
    assert [line.split()[0] for line in lines] == [f"builtin:{n}" for n in NAMES]
