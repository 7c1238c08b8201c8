"""Splitting one 3DGS scene into objects (``scene.split``): by a per-splat label property
of the .ply (``split: label``) or by connected components of the splat centres
(``split: components``).

Parts are identified by an integer: the label value, or the component's rank by size
(0 = the most splats). Nothing here transforms, simulates or renders.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motionphysics.errors import UserInputError
from motionphysics.scene.gaussians import GaussianScene

__all__ = ["LINK_SPACINGS", "MIN_PART_FRACTION", "part_labels", "split_parts", "select_part"]

LINK_SPACINGS = 4.0
"""Two splats belong to one component when their centres are closer than this many
median nearest-neighbour spacings (a surface sampled densely stays one piece; a gap of a
few spacings separates objects)."""
MIN_PART_FRACTION = 0.01
"""Components with fewer splats than this fraction of the scene (floaters) join the
nearest larger component instead of becoming objects."""


def _read_label(source: str, prop: str) -> np.ndarray:
    from motionphysics.scene import ply

    path = Path(source).expanduser()
    if source.startswith("builtin:") or path.suffix.lower() != ".ply":
        raise UserInputError(
            f"scene.split: label needs a 3DGS .ply with a per-splat {prop!r} property, got {source}"
        )
    data = ply._open(path)  # noqa: SLF001 - the package's own reader
    vertex = data["vertex"]
    names = [p.name for p in vertex.properties]
    if prop not in names:
        raise UserInputError(
            f"{source}: no per-splat property {prop!r} to split by (scene.split_property); "
            f"the file has {', '.join(names)}"
        )
    values = np.asarray(vertex[prop])
    if not np.all(np.isfinite(values)) or np.any(values != np.round(values)):
        raise UserInputError(f"{source}: property {prop!r} must hold integer labels")
    return values.astype(np.int64)


def _components(scene: GaussianScene) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pts = scene.means.double().numpy()
    n = len(pts)
    if n < 2:
        return np.zeros(n, dtype=np.int64)
    tree = cKDTree(pts)
    d, _ = tree.query(pts, k=2)
    spacing = float(np.median(d[:, 1]))
    pairs = tree.query_pairs(max(LINK_SPACINGS * spacing, 1e-12), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    sizes = np.bincount(comp)
    big = np.nonzero(sizes >= max(1, MIN_PART_FRACTION * n))[0]
    if len(big) == 0:
        return np.zeros(n, dtype=np.int64)
    # a floater joins, whole, the big component nearest to it
    in_big = np.isin(comp, big)
    if not in_big.all():
        dist, near = cKDTree(pts[in_big]).query(pts[~in_big])
        target = comp[in_big][near]
        small = comp[~in_big]
        order = np.lexsort((dist, small))  # per floater, its closest point first
        first = order[np.r_[True, small[order][1:] != small[order][:-1]]]
        lookup = dict(zip(small[first].tolist(), target[first].tolist(), strict=True))
        comp[~in_big] = np.array([lookup[c] for c in small.tolist()], dtype=comp.dtype)
    # rank by size: 0 = most splats
    order = big[np.argsort(-sizes[big], kind="stable")]
    rank = np.full(comp.max() + 1, -1, dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank[comp]


def part_labels(scene: GaussianScene, source: str, how: str, prop: str = "label") -> np.ndarray:
    """Part id of every splat [N] int64 (``how``: ``label`` or ``components``)."""
    if how == "label":
        labels = _read_label(source, prop)
        if len(labels) != scene.num:
            raise UserInputError(f"{source}: {len(labels)} labels for {scene.num} splats")
        return labels
    if how == "components":
        return _components(scene)
    raise UserInputError(f"scene.split: expected label or components, got {how!r}")


def split_parts(scene: GaussianScene, source: str, how: str, prop: str = "label") -> list[int]:
    """The part ids of a scene, in order (labels ascending; components by size)."""
    return [int(v) for v in np.unique(part_labels(scene, source, how, prop))]


def select_part(
    scene: GaussianScene, source: str, how: str, part: int, prop: str = "label", where: str = ""
) -> GaussianScene:
    """The splats of one part (``UserInputError`` naming ``where`` when it has none)."""
    labels = part_labels(scene, source, how, prop)
    keep = labels == int(part)
    if not keep.any():
        have = ", ".join(str(v) for v in np.unique(labels)[:20])
        raise UserInputError(
            f"{where or source}: part {part} not found when splitting by {how} (parts: {have})"
        )
    import torch

    return scene.subset(torch.from_numpy(keep))
