"""Meshes to surface Gaussians: on-surface, face-aligned, area-weighted, coloured."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from motionphysics.errors import UserInputError
from motionphysics.scene import load_scene
from motionphysics.scene.mesh import (
    GREY,
    load_mesh,
    mesh_to_gaussians,
    sample_triangles,
    shade_colours,
)
from motionphysics.scene.ply import ply_kind

EXTENTS = np.array([1.0, 2.0, 3.0])


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=EXTENTS)


def _check_box_splats(s, n_expected):
    p = s.means.double().numpy()
    assert abs(s.num - n_expected) < 0.1 * n_expected
    half = EXTENTS / 2
    # On the surface: every point on some face (|coord| = half extent on one axis).
    on_face = np.abs(np.abs(p) - half) < 1e-5  # float32 positions of O(1): 1e-5 is ~100 ulp
    assert on_face.any(axis=1).all()
    assert (np.abs(p) <= half + 1e-5).all()
    # Flat and face-aligned: the thin (third) axis is the face normal.
    r = s.rotation_matrices().double().numpy()
    normal_axis = np.abs(r[:, :, 2])
    face_axis = np.argmax(on_face, axis=1)
    np.testing.assert_allclose(normal_axis[np.arange(len(p)), face_axis], 1.0, atol=1e-5)
    sc = s.scales.numpy()
    np.testing.assert_allclose(sc[:, 2], 0.1 * sc[:, 0], rtol=1e-5)
    np.testing.assert_allclose(sc[:, 0], sc[:, 1], rtol=1e-6)
    # Area-weighted: the share of splats on the faces normal to axis a is that pair's area share.
    areas = np.array([EXTENTS[1] * EXTENTS[2], EXTENTS[0] * EXTENTS[2], EXTENTS[0] * EXTENTS[1]])
    share = np.bincount(face_axis, minlength=3) / len(p)
    # Even (thinned) sampling on axis-aligned faces: the share follows area to within a few
    # percent (cube-grid quantisation at the face borders); i.i.d. sampling would be ~1%.
    np.testing.assert_allclose(share, areas / areas.sum(), atol=0.03)
    # No colours in the file: the default-light shading of the outward face normal.
    outward = np.zeros_like(p)
    idx = np.arange(len(p))
    outward[idx, face_axis] = np.sign(p[idx, face_axis])
    np.testing.assert_allclose(s.base_colors().numpy(), shade_colours(outward), atol=1e-5)
    np.testing.assert_allclose(s.opacities.numpy(), 0.9, atol=1e-6)


@pytest.mark.parametrize("ext", [".obj", ".stl", ".off", ".ply"])
def test_mesh_file_to_splats(tmp_path, box, ext):
    path = tmp_path / f"box{ext}"
    box.export(str(path))
    if ext == ".ply":
        assert ply_kind(path) == "mesh"
    if ext == ".obj":  # the full dispatch once, at the default splat count
        _check_box_splats(load_scene(str(path)), 20000)
    else:
        _check_box_splats(load_mesh(path, count=4000), 4000)


def test_iid_sampling_is_area_weighted(box):
    tri = np.asarray(box.triangles)
    face, bary, pts = sample_triangles(tri, 40000, np.random.default_rng(0), even=False)
    assert len(face) == 40000
    np.testing.assert_allclose(bary.sum(1), 1.0)
    assert (bary >= 0).all()
    area = box.area_faces
    counts = np.bincount(face, minlength=len(tri))
    # Binomial counts: 4 standard deviations per face.
    expected = 40000 * area / area.sum()
    assert (np.abs(counts - expected) < 4 * np.sqrt(expected) + 1).all()


def test_sampling_is_deterministic(box):
    a = mesh_to_gaussians(box, count=500, seed=3)
    b = mesh_to_gaussians(box, count=500, seed=3)
    c = mesh_to_gaussians(box, count=500, seed=4)
    assert torch.equal(a.means, b.means) and not torch.equal(a.means, c.means)


def test_face_and_vertex_colours(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=2)
    fc = np.where(m.triangles_center[:, 2:3] > 0, [[255, 0, 0, 255]], [[0, 0, 255, 255]]).astype(
        np.uint8
    )
    m.visual.face_colors = fc
    path = tmp_path / "coloured.ply"
    m.export(str(path))
    s = load_mesh(path, count=3000)
    col = s.base_colors().numpy()
    z = s.means[:, 2].numpy()
    # Faces with centre above z=0 are red. Facet edges of this icosphere are ~0.3 long, so a
    # point with |z| > 0.3 lies on a face whose centre has the same sign of z.
    top, bottom = z > 0.3, z < -0.3
    np.testing.assert_allclose(col[top], np.tile([1, 0, 0], (top.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(col[bottom], np.tile([0, 0, 1], (bottom.sum(), 1)), atol=1e-6)

    v = trimesh.creation.icosphere(subdivisions=2)
    vc = np.zeros((len(v.vertices), 4), np.uint8)
    vc[:, 1] = np.round(255 * (v.vertices[:, 0] + 1) / 2).astype(np.uint8)  # green ramps with x
    vc[:, 3] = 255
    v.visual.vertex_colors = vc
    s = mesh_to_gaussians(v, count=2000)
    g = s.base_colors()[:, 1].double().numpy()
    x = s.means[:, 0].double().numpy()
    # Barycentric interpolation of a linear ramp is linear in x up to facet flattening.
    np.testing.assert_allclose(g, (x + 1) / 2, atol=0.02)


@pytest.mark.parametrize("ext", [".glb", ".obj"])
def test_texture_colours(tmp_path, ext):
    from PIL import Image

    # A unit square in the xy plane, uv = (x, y); texture left half red, right half green.
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    img = np.zeros((16, 16, 3), np.uint8)
    img[:, :8] = [255, 0, 0]
    img[:, 8:] = [0, 255, 0]
    if ext == ".glb":  # glTF: colour = baseColorTexture x baseColorFactor (default 1)
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(img))
    else:  # OBJ: map_Kd
        material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(img))
    visual = trimesh.visual.TextureVisuals(uv=verts[:, :2], material=material)
    m = trimesh.Trimesh(verts, faces, visual=visual, process=False)
    path = tmp_path / f"textured{ext}"
    m.export(str(path))
    s = load_scene(str(path))
    col = s.base_colors().numpy()
    x = s.means[:, 0].numpy()
    left, right = x < 0.45, x > 0.55  # nearest-texel lookup: exact away from the seam
    assert left.sum() > 100 and right.sum() > 100
    np.testing.assert_allclose(col[left], np.tile([1, 0, 0], (left.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(col[right], np.tile([0, 1, 0], (right.sum(), 1)), atol=1e-6)


def test_bad_meshes(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_text("# nothing\n")
    with pytest.raises(UserInputError) as e:
        load_scene(str(p))
    assert "empty.obj" in str(e.value) and "\n" not in str(e.value)
    flat = trimesh.Trimesh(
        np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), np.array([[0, 1, 2]])
    )
    with pytest.raises(UserInputError, match="area"):
        mesh_to_gaussians(flat, origin="flat.obj")


def _splat_normals(s) -> np.ndarray:
    """Thin (third) axis of each flat splat, [N, 3]."""
    return s.rotation_matrices().double().numpy()[:, :, 2]


def test_uncoloured_sphere_gets_default_light_shading():
    from motionphysics.scene.mesh import SHADE_ALBEDO, SHADE_AMBIENT, SHADE_LIGHT

    def law(s):
        """Expected grey per splat from the documented constants (not from shade_colours)."""
        p = s.means.double().numpy()
        n = _splat_normals(s)  # facet normal of each splat (its thin axis) ...
        n *= np.sign((n * p).sum(1, keepdims=True))  # ... outwards (the sphere is centred)
        cos = n @ np.asarray(SHADE_LIGHT)
        return cos, SHADE_ALBEDO * (SHADE_AMBIENT + (1 - SHADE_AMBIENT) * np.maximum(cos, 0.0))

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    s = mesh_to_gaussians(sphere, count=3000, seed=1)
    cos, want = law(s)
    got = s.base_colors().double().numpy()
    np.testing.assert_allclose(got, np.repeat(want[:, None], 3, 1), atol=1e-5)
    lit, dark = got[cos > 0.9, 0].mean(), got[cos < -0.3, 0].mean()
    assert lit > 0.75 and abs(dark - SHADE_ALBEDO * SHADE_AMBIENT) < 1e-6
    # Faces wound inwards (same closed surface): the sign is fixed, the law still holds.
    inv = sphere.copy()
    inv.invert()
    s_inv = mesh_to_gaussians(inv, count=3000, seed=1)
    _, want_inv = law(s_inv)
    np.testing.assert_allclose(
        s_inv.base_colors().double().numpy(), np.repeat(want_inv[:, None], 3, 1), atol=1e-5
    )
    # Off: flat mid grey, as before.
    flat = mesh_to_gaussians(sphere, count=3000, seed=1, shade=False)
    np.testing.assert_allclose(flat.base_colors().numpy(), np.tile(GREY, (flat.num, 1)), atol=1e-6)


def test_open_mesh_is_lit_on_both_sides_and_coloured_mesh_untouched():
    # A single square facing -z (away from the light): an open surface has no "outside",
    # so it is lit as if it faced the light (|n . l|).
    quad = trimesh.Trimesh(
        vertices=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
        faces=[[0, 2, 1], [0, 3, 2]],
        process=False,
    )
    s = mesh_to_gaussians(quad, count=500)
    assert _splat_normals(s)[:, 2].max() < -0.99 or _splat_normals(s)[:, 2].min() > 0.99
    want = shade_colours(np.tile([0.0, 0.0, 1.0], (s.num, 1)))
    np.testing.assert_allclose(s.base_colors().numpy(), want, atol=1e-5)
    box = trimesh.creation.box(extents=EXTENTS)
    box.visual.face_colors = np.tile([200, 30, 40, 255], (len(box.faces), 1))
    c = mesh_to_gaussians(box, count=500).base_colors().numpy()
    np.testing.assert_allclose(c, np.tile(np.array([200, 30, 40]) / 255, (len(c), 1)), atol=1e-5)


def test_scene_shade_key_and_load_scene(tmp_path):
    from motionphysics.config import config_from_dict

    assert config_from_dict({}).scene.shade is True
    assert config_from_dict({"scene": {"shade": False}}).scene.shade is False
    path = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2).export(str(path))
    shaded = load_scene(str(path)).base_colors().numpy()
    flat = load_scene(str(path), shade=False).base_colors().numpy()
    assert shaded.std(axis=0).max() > 0.1
    np.testing.assert_allclose(flat, 0.5, atol=1e-6)
