"""Bundled example scenes, built procedurally (no download, deterministic).

Every builtin is a set of surface splats (about 4,000 flat Gaussians, opacity 0.9),
centred at the origin (bounding box of the splat centres) with its largest extent 1,
so the run config's ``scale`` gives its size in metres. The world is z-up.

Compound shapes (``bird``, ``duck``) are unions of ellipsoids; samples of one part that
fall inside another part are dropped, so only the outer surface carries splats and
prepare's voxel fill sees one closed object.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from motionphysics.errors import UserInputError
from motionphysics.scene.gaussians import GaussianScene
from motionphysics.scene.mesh import SIGMA_FACTOR, sample_triangles, surface_splats

__all__ = ["list_builtins", "build_builtin", "BUILTIN_SPLATS"]

BUILTIN_SPLATS = 4000
"""Surface samples drawn per builtin (compound shapes keep slightly fewer: hidden ones go)."""
_OPACITY = 0.9
_SEED = 0

Colour = Callable[[np.ndarray], np.ndarray]  # points (M,3) -> RGB (M,3) in [0,1]


def _solid(rgb) -> Colour:
    c = np.asarray(rgb, dtype=np.float64)
    return lambda p: np.tile(c, (len(p), 1))


def _checker(rgb, cell: float = 0.09, dark: float = 0.35) -> Colour:
    """A 3D checkerboard texture: the part colour alternating with a darker shade."""
    c = np.asarray(rgb, dtype=np.float64)

    def colour(p):
        parity = np.floor(p / cell).astype(np.int64).sum(axis=1) % 2
        # A stripe of white within the light squares adds a second spatial frequency.
        stripe = (np.sin(p[:, 2] * 2 * np.pi / (0.5 * cell)) > 0.6)[:, None]
        light = np.where(stripe, 1.0, c)
        return np.where(parity[:, None] == 0, light, c * dark)

    return colour


def _rot(axis: str, degrees: float) -> np.ndarray:
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


@dataclass
class _Part:
    triangles: np.ndarray  # (F, 3, 3) facets used for area-weighted sampling [arbitrary units]
    colour: Colour
    centre: np.ndarray | None = None  # ellipsoid parts: exact surface and inside test
    radii: np.ndarray | None = None
    rot: np.ndarray | None = None  # (3,3) local -> world

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Points moved onto the exact ellipsoid surface, and its normals (None: use facets)."""
        if self.radii is None:
            return p, None
        local = (p - self.centre) @ self.rot  # R^T (p - c), row vectors
        q = local / np.linalg.norm(local / self.radii, axis=1, keepdims=True)
        n = (q / self.radii**2) @ self.rot.T
        return q @ self.rot.T + self.centre, n

    def inside(self, p: np.ndarray) -> np.ndarray:
        if self.radii is None:
            return np.zeros(len(p), dtype=bool)
        local = (p - self.centre) @ self.rot
        return np.linalg.norm(local / self.radii, axis=1) < 1.0 - 1e-9


def _ellipsoid(centre, radii, colour: Colour, rot=None) -> _Part:
    import trimesh

    rot = np.eye(3) if rot is None else np.asarray(rot, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    tri = np.asarray(sphere.triangles) * radii @ rot.T + centre
    return _Part(tri, colour, centre, radii, rot)


def _mesh_part(mesh, colour: Colour) -> _Part:
    return _Part(np.asarray(mesh.triangles, dtype=np.float64), colour)


def _assemble(parts: list[_Part], count: int = BUILTIN_SPLATS, seed: int = _SEED) -> GaussianScene:
    rng = np.random.default_rng(seed)
    tri = np.concatenate([p.triangles for p in parts])
    owner = np.concatenate([np.full(len(p.triangles), i) for i, p in enumerate(parts)])
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face, _, pts = sample_triangles(tri, count, rng)
    e1 = tri[face, 1] - tri[face, 0]
    normals = np.cross(e1, tri[face, 2] - tri[face, 0])
    who = owner[face]
    colours = np.empty((len(face), 3))
    keep = np.ones(len(face), dtype=bool)
    for i, part in enumerate(parts):
        sel = who == i
        if not sel.any():
            continue
        p, n = part.project(pts[sel])
        pts[sel] = p
        if n is not None:
            normals[sel] = n
        colours[sel] = part.colour(p)
        for j, other in enumerate(parts):
            if j != i:
                keep[np.nonzero(sel)[0][other.inside(p)]] = False
    pts, normals, e1, colours = pts[keep], normals[keep], e1[keep], colours[keep]
    sigma = SIGMA_FACTOR * np.sqrt(area.sum() / count)
    scene = surface_splats(pts, normals, e1, colours, sigma, opacity=_OPACITY)
    return _normalise(scene)


def _normalise(scene: GaussianScene) -> GaussianScene:
    """Centre the bounding box of the means at the origin and scale its largest side to 1."""
    lo = scene.means.min(0).values.double()
    hi = scene.means.max(0).values.double()
    centre = 0.5 * (lo + hi)
    s = 1.0 / float((hi - lo).max())
    out = scene.clone()
    out.means = ((scene.means.double() - centre) * s).float()
    out.log_scales = scene.log_scales + float(np.log(s))
    return out


# ---- the shapes ------------------------------------------------------------------------


def _sphere():
    return [_ellipsoid((0, 0, 0), (0.5, 0.5, 0.5), _solid((0.85, 0.2, 0.2)))]


def _cube():
    import trimesh

    return [_mesh_part(trimesh.creation.box(extents=(1, 1, 1)), _solid((0.2, 0.55, 0.85)))]


def _column():
    import trimesh

    return [_mesh_part(trimesh.creation.box(extents=(0.5, 0.5, 1.0)), _solid((0.78, 0.74, 0.64)))]


def _torus():
    import trimesh

    m = trimesh.creation.torus(
        major_radius=0.35, minor_radius=0.15, major_sections=96, minor_sections=48
    )
    return [_mesh_part(m, _solid((0.86, 0.58, 0.32)))]


def _rod():
    import trimesh

    m = trimesh.creation.cylinder(radius=0.06, height=1.0, sections=48)
    m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))  # z -> x
    return [_mesh_part(m, _solid((0.62, 0.63, 0.68)))]


_BIRD_COLOURS = {
    "body": (0.22, 0.42, 0.85),
    "head": (0.88, 0.22, 0.18),
    "beak": (1.0, 0.72, 0.08),
    "wing": (0.1, 0.22, 0.5),
    "tail": (0.15, 0.55, 0.25),
    "eye": (0.03, 0.03, 0.03),
}


def _bird(
    style: str = "parts", parts: tuple[str, ...] = ("body", "head", "beak", "wing", "tail", "eye")
):
    def col(name):
        rgb = _BIRD_COLOURS[name]
        if style == "red":  # the paper's colour variant: body red, head blue
            rgb = {"body": (0.85, 0.2, 0.18), "head": (0.22, 0.42, 0.85)}.get(name, rgb)
        if style == "plain":
            return _solid((0.6, 0.6, 0.6))
        if style == "textured":
            return _checker(rgb)
        return _solid(rgb)

    all_parts = [
        ("body", _ellipsoid((0, 0, 0), (0.5, 0.28, 0.3), col("body"))),
        ("head", _ellipsoid((0.48, 0, 0.3), (0.2, 0.2, 0.2), col("head"))),
        ("beak", _ellipsoid((0.72, 0, 0.28), (0.13, 0.05, 0.04), col("beak"))),
        ("wing", _ellipsoid((-0.05, 0.26, 0.06), (0.34, 0.05, 0.16), col("wing"), _rot("x", -12))),
        ("wing", _ellipsoid((-0.05, -0.26, 0.06), (0.34, 0.05, 0.16), col("wing"), _rot("x", 12))),
        ("tail", _ellipsoid((-0.6, 0, 0.14), (0.26, 0.12, 0.03), col("tail"), _rot("y", -25))),
        ("eye", _ellipsoid((0.6, 0.13, 0.37), (0.035, 0.035, 0.035), col("eye"))),
        ("eye", _ellipsoid((0.6, -0.13, 0.37), (0.035, 0.035, 0.035), col("eye"))),
    ]
    return [part for name, part in all_parts if name in parts]


def _duck():
    yellow, dark_yellow = (0.98, 0.85, 0.12), (0.9, 0.7, 0.05)
    orange, black = (0.98, 0.45, 0.05), (0.03, 0.03, 0.03)
    return [
        _ellipsoid((0, 0, 0), (0.55, 0.4, 0.3), _solid(yellow)),
        _ellipsoid((0.33, 0, 0.42), (0.24, 0.24, 0.24), _solid(yellow)),
        _ellipsoid((0.6, 0, 0.37), (0.15, 0.1, 0.045), _solid(orange)),
        _ellipsoid((-0.55, 0, 0.14), (0.16, 0.12, 0.08), _solid(dark_yellow), _rot("y", -35)),
        _ellipsoid((-0.05, 0.37, 0.05), (0.3, 0.06, 0.15), _solid(dark_yellow), _rot("x", -10)),
        _ellipsoid((-0.05, -0.37, 0.05), (0.3, 0.06, 0.15), _solid(dark_yellow), _rot("x", 10)),
        _ellipsoid((0.5, 0.13, 0.5), (0.035, 0.035, 0.035), _solid(black)),
        _ellipsoid((0.5, -0.13, 0.5), (0.035, 0.035, 0.035), _solid(black)),
    ]


_BUILTINS: dict[str, tuple[str, Callable[[], list[_Part]]]] = {
    "sphere": ("red ball, diameter 1", _sphere),
    "cube": ("blue cube, side 1", _cube),
    "column": ("stone-coloured box, twice as tall (z) as wide", _column),
    "torus": ("orange ring in the xy plane (donut-like), outer diameter 1", _torus),
    "rod": ("grey cylinder along x, length 1, diameter 0.12", _rod),
    "bird": (
        "bird facing +x: blue body, red head, yellow beak, dark wings, green tail",
        lambda: _bird("parts"),
    ),
    "duck": ("rubber duck facing +x: yellow body and head, orange beak, tail and wings", _duck),
    "bird_textured": (
        "the bird shape with a high-contrast checker texture (appearance study)",
        lambda: _bird("textured"),
    ),
    "bird_plain": ("the bird shape in one uniform grey (appearance study)", lambda: _bird("plain")),
    "bird_red": ("the bird with a red body and blue head (colour variant)", lambda: _bird("red")),
    "bird_simple": (
        "the bird without tail and beak (geometry variant)",
        lambda: _bird("parts", ("body", "head", "wing", "eye")),
    ),
}


def list_builtins() -> list[tuple[str, str]]:
    """(name, one-line description) of every builtin scene, in display order."""
    return [(name, desc) for name, (desc, _) in _BUILTINS.items()]


def build_builtin(name: str) -> GaussianScene:
    """Build builtin scene ``name`` (deterministic). Unknown name -> UserInputError."""
    if name not in _BUILTINS:
        raise UserInputError(
            f"builtin:{name}: unknown builtin scene; expected one of {', '.join(_BUILTINS)}"
        )
    scene = _assemble(_BUILTINS[name][1]())
    return scene.to(torch.float32).validate(f"builtin:{name}")
