"""Meshes to Gaussians: flat splats sampled on a triangle surface.

A mesh (.obj .stl .off .glb, mesh .ply) is read with trimesh; points are drawn on its
surface with probability proportional to triangle area (seeded, so deterministic), and
each point becomes a flat Gaussian: two axes in the face plane with standard deviation
``0.6 * sqrt(area / count)`` (neighbouring splats overlap at about one sigma, so the
surface renders closed), the normal axis ``thickness_ratio`` times thinner. Colours
come from the mesh's texture, vertex colours or face colours.

A mesh with none of those would render as one flat grey (a sphere reads as a disc),
so by default (``shade=True``, run config ``scene.shade``) its splats get a shading
baked into their colour: Lambert's law under one directional light plus ambient,
``colour = SHADE_ALBEDO * (SHADE_AMBIENT + (1 - SHADE_AMBIENT) * max(0, n . l))``
with ``l = SHADE_LIGHT`` (from +x +y +z, in the mesh file's own coordinates, so the
top and front of both z-up and y-up files are lit; the baked shade then moves and
rotates with the material, like paint). Normals ``n`` point outwards when the mesh
is closed with consistent winding (its signed volume decides the sign); on open or
inconsistently wound meshes the side facing away from the light cannot be told, so
both sides are lit alike (``|n . l|``). With ``shade=False`` such meshes are mid
grey (``GREY``). Meshes with colours or a texture are never shaded.

Only the surface is represented here; interior particles of closed objects are added
by :func:`motionphysics.scene.prepare.prepare` (voxel fill). Mesh units are kept as
they are (the run config's ``scale`` sizes the object).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from motionphysics.errors import UserInputError
from motionphysics.scene.gaussians import GaussianScene, rotmat_to_quat

__all__ = [
    "MESH_EXTENSIONS",
    "DEFAULT_MESH_SPLATS",
    "load_mesh",
    "mesh_to_gaussians",
    "sample_triangles",
    "surface_splats",
    "shade_colours",
    "SHADE_LIGHT",
    "SHADE_AMBIENT",
    "SHADE_ALBEDO",
]

MESH_EXTENSIONS = (".obj", ".stl", ".off", ".glb", ".gltf", ".ply")
DEFAULT_MESH_SPLATS = 20000
"""Splats drawn on a mesh file's surface (before prepare's opacity filter and downsampling)."""
SIGMA_FACTOR = 0.6
"""In-plane standard deviation of a surface splat, in units of the mean sample spacing."""
GREY = (0.5, 0.5, 0.5)
"""Colour of a mesh without colours or texture when ``shade`` is off."""
SHADE_LIGHT = (0.5773502691896258, 0.5773502691896258, 0.5773502691896258)
"""Unit direction towards the default light, mesh file coordinates (from +x +y +z)."""
SHADE_AMBIENT = 0.3
"""Share of the albedo seen on faces the light does not reach."""
SHADE_ALBEDO = 0.8
"""Grey level of a face lit head-on (the baked colour spans 0.24 .. 0.8)."""


def _cell_keys(points: np.ndarray, h: float) -> np.ndarray:
    """One int64 per cube of side h holding each point (M,3) -> (M,); 1-D unique is fast."""
    c = np.floor(points / h).astype(np.int64)
    c -= c.min(axis=0)
    r = c.max(axis=0) + 1
    return (c[:, 0] * r[1] + c[:, 1]) * r[2] + c[:, 2]


def sample_triangles(
    triangles: np.ndarray, count: int, rng: np.random.Generator, even: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted samples on triangles.

    triangles: (F, 3, 3) float64 vertex positions [m]. Returns ``face`` (M,) int64 face
    indices, ``bary`` (M, 3) barycentric weights, ``points`` (M, 3) [m].

    ``even=False``: M = count i.i.d. uniform samples. ``even=True`` (default): 8 x count
    uniform candidates thinned to one per cube of a grid whose size is tuned so that
    about ``count`` remain (M within a few percent of count). Plain i.i.d. samples leave
    gaps several times the mean spacing (holes in the rendered surface and in the voxel
    shell); thinning bounds every gap by about one cube diagonal.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    if not np.isfinite(total) or total <= 0:
        raise ValueError("triangles have zero total area")
    m = count * 8 if even else count
    face = rng.choice(len(tri), size=m, p=area / total)
    u = rng.random(m)
    v = rng.random(m)
    flip = u + v > 1  # reflect into the triangle: uniform on its area
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    bary = np.stack([1 - u - v, u, v], axis=1)
    points = np.einsum("mk,mkd->md", bary, tri[face])
    if even:
        h = np.sqrt(total / count)
        keep = np.arange(m)
        for _ in range(8):  # n(h) ~ 1/h^2: a few fixed-point steps land within ~1%
            _, keep = np.unique(_cell_keys(points, h), return_index=True)
            if abs(len(keep) - count) <= 0.01 * count:
                break
            h *= np.sqrt(len(keep) / count)
        keep = np.sort(keep)  # first candidate of each cube: a random one (candidates are i.i.d.)
        face, bary, points = face[keep], bary[keep], points[keep]
    return face.astype(np.int64), bary, points


def surface_splats(
    points: np.ndarray,
    normals: np.ndarray,
    tangents: np.ndarray,
    colors: np.ndarray,
    sigma: float,
    thickness_ratio: float = 0.1,
    opacity: float = 0.9,
) -> GaussianScene:
    """Flat Gaussians lying in the tangent planes.

    points (M,3) [m]; normals (M,3) and tangents (M,3) (need not be unit; tangents are
    made orthogonal to the normals here); colors (M,3) RGB in [0,1]; sigma [m] in-plane
    standard deviation; the normal axis gets ``thickness_ratio * sigma``.
    """
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    t = tangents - (tangents * n).sum(1, keepdims=True) * n
    tn = np.linalg.norm(t, axis=1, keepdims=True)
    # A tangent parallel to the normal (degenerate input): use any perpendicular axis.
    alt = np.cross(n, np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    t = np.where(
        tn > 1e-9, t / np.maximum(tn, 1e-300), alt / np.linalg.norm(alt, axis=1, keepdims=True)
    )
    b = np.cross(n, t)
    rot = np.stack([t, b, n], axis=2)  # columns = axes; det +1 since t x b = n
    quats = rotmat_to_quat(torch.from_numpy(rot)).numpy()
    m = len(points)
    scales = np.tile([sigma, sigma, sigma * thickness_ratio], (m, 1))
    return GaussianScene.from_activated(
        means=points,
        scales=scales,
        rotations=quats,
        opacities=np.full(m, opacity),
        colors=np.clip(colors, 0.0, 1.0),
    )


def shade_colours(
    normals: np.ndarray, two_sided: bool | np.ndarray = False, light=SHADE_LIGHT
) -> np.ndarray:
    """Baked grey shading of surface points with ``normals`` (M, 3) (need not be unit).

    Returns RGB (M, 3) in [0, 1] by the law in the module docstring; ``two_sided``
    (bool or (M,) bool) lights both sides of a point's plane (``|n . l|``).
    """
    n = np.asarray(normals, dtype=np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    lv = np.asarray(light, dtype=np.float64)
    lv = lv / np.linalg.norm(lv)
    cos = n @ lv
    cos = np.where(two_sided, np.abs(cos), np.maximum(cos, 0.0))
    grey = SHADE_ALBEDO * (SHADE_AMBIENT + (1.0 - SHADE_AMBIENT) * cos)
    return np.repeat(grey[:, None], 3, axis=1)


def _outward_sign(mesh) -> float | None:
    """+1 / -1 when the mesh is closed and consistently wound (outward / inward faces), else None.

    Judged on a copy with coincident vertices merged (an STL stores a triangle soup);
    merging keeps each face's winding, so the sign holds for the original faces.
    """
    import trimesh

    try:
        probe = trimesh.Trimesh(
            vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces), process=True
        )
        if probe.is_watertight and probe.is_winding_consistent:
            vol = float(probe.volume)
            if vol != 0 and np.isfinite(vol):
                return 1.0 if vol > 0 else -1.0
    except Exception:  # trimesh's topology checks can fail on odd input: treat as open
        return None
    return None


def _colour_sampler(mesh) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """A function (face (M,), bary (M,3)) -> RGB (M,3) in [0,1] for this trimesh mesh.

    None when the mesh has no texture, vertex colours or face colours.
    """
    visual = getattr(mesh, "visual", None)
    kind = getattr(visual, "kind", None)
    faces = np.asarray(mesh.faces)
    if kind == "texture":
        uv = getattr(visual, "uv", None)
        material = getattr(visual, "material", None)
        image = None
        for attr in ("image", "baseColorTexture"):
            image = getattr(material, attr, None) if material is not None else None
            if image is not None:
                break
        factor = np.ones(3)
        main = getattr(material, "main_color", None) if material is not None else None
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            img = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0  # [H, W, 3]
            bcf = getattr(material, "baseColorFactor", None)
            if bcf is not None:
                factor = np.asarray(bcf, dtype=np.float64)[:3] / (255.0 if np.max(bcf) > 1 else 1.0)
            uvs = np.asarray(uv, dtype=np.float64)
            h, w = img.shape[:2]

            def tex(face, bary):
                p = np.einsum("mk,mkd->md", bary, uvs[faces[face]])
                # UV origin is bottom-left; images are stored top row first. Wrap (repeat).
                x = np.mod(p[:, 0], 1.0) * (w - 1)
                y = (1.0 - np.mod(p[:, 1], 1.0)) * (h - 1)
                return img[np.rint(y).astype(int), np.rint(x).astype(int)] * factor

            return tex
        if main is not None:
            col = np.asarray(main, dtype=np.float64)[:3] / 255.0
            return lambda face, bary: np.tile(col, (len(face), 1))
    elif kind == "vertex":
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0  # [V, 3]
        return lambda face, bary: np.einsum("mk,mkd->md", bary, vc[faces[face]])
    elif kind == "face":
        fc = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0  # [F, 3]
        return lambda face, bary: fc[face]
    return None


def mesh_to_gaussians(
    meshes,
    count: int = DEFAULT_MESH_SPLATS,
    seed: int = 0,
    thickness_ratio: float = 0.1,
    opacity: float = 0.9,
    origin: str = "<mesh>",
    shade: bool = True,
) -> GaussianScene:
    """Surface splats on one trimesh mesh or a list of them (area-weighted over all).

    Returns about ``count`` Gaussians (float32; see :func:`sample_triangles`). Meshes
    without colours or texture get the baked shading of the module docstring when
    ``shade`` (else :data:`GREY`). Raises UserInputError naming ``origin`` when
    there is no triangle with positive area or the vertices hold NaN/Inf.
    """
    import trimesh

    if isinstance(meshes, trimesh.Trimesh):
        meshes = [meshes]
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces) > 0]
    if not meshes:
        raise UserInputError(f"{origin}: contains no triangles; expected a surface mesh")
    tris, owners, local = [], [], []
    for i, m in enumerate(meshes):
        t = np.asarray(m.triangles, dtype=np.float64)
        if not np.isfinite(t).all():
            raise UserInputError(f"{origin}: mesh vertices contain NaN or Inf")
        tris.append(t)
        owners.append(np.full(len(t), i))
        local.append(np.arange(len(t)))
    tri = np.concatenate(tris)
    owner = np.concatenate(owners)
    local_face = np.concatenate(local)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum())
    if total <= 0:
        raise UserInputError(f"{origin}: mesh has zero surface area")
    # Faces with a tiny area relative to the largest have unreliable normals; they carry
    # a negligible share of the samples, so they are left out.
    ok = area > 1e-12 * area.max()
    tri, owner, local_face = tri[ok], owner[ok], local_face[ok]
    rng = np.random.default_rng(seed)
    face, bary, points = sample_triangles(tri, count, rng)
    e1 = tri[face, 1] - tri[face, 0]
    normals = np.cross(e1, tri[face, 2] - tri[face, 0])
    colors = np.empty((len(face), 3))
    for i, m in enumerate(meshes):
        sel = owner[face] == i
        if not sel.any():
            continue
        sampler = _colour_sampler(m)
        if sampler is not None:
            colors[sel] = sampler(local_face[face[sel]], bary[sel])
        elif shade:
            sign = _outward_sign(m)
            colors[sel] = shade_colours(
                normals[sel] * (1.0 if sign is None else sign), two_sided=sign is None
            )
        else:
            colors[sel] = GREY
    sigma = SIGMA_FACTOR * np.sqrt(total / count)
    return surface_splats(points, normals, e1, colors, sigma, thickness_ratio, opacity).validate(
        origin
    )


def load_mesh(
    path: str | Path, count: int = DEFAULT_MESH_SPLATS, seed: int = 0, shade: bool = True
) -> GaussianScene:
    """Read a mesh file with trimesh and return surface splats (see :func:`mesh_to_gaussians`)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path}: file not found")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as err:  # trimesh raises many types for unreadable files
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserInputError(f"{path}: could not read the mesh ({msg})") from None
    if isinstance(loaded, trimesh.Scene):
        meshes = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
    else:
        meshes = [loaded]
    return mesh_to_gaussians(meshes, count=count, seed=seed, origin=str(path), shade=shade)
