"""The scene phase of the assembly for a region of a capture (``scene.region``).

What :mod:`motionphysics.assembly` asks of a run whose config simulates a region of a
capture and keeps the rest (the static scene, ``SimScene.static_splats``):

* :func:`region_ground` -- the support. With a region and ``boundary_conditions`` left
  out, no floor is added: the static scene holds the object up (its collider,
  ``scene.region.StaticCollider``); ``run.yaml`` records ``boundary_conditions: []``.
* :func:`static_splats_view` -- the static splats as the renderer draws them (unchanged
  means and covariances, colours from their SH for the camera), appended to every frame.
* :func:`static_lines` -- the summary's ``static`` line and the support warning.

This module builds no simulation and writes no file.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "MIN_RESOLVED_CELLS",
    "has_region",
    "region_ground",
    "resolution_line",
    "static_lines",
    "static_splats_view",
]

STATIC_GROUND = (
    "ground: the static scene outside scene.region holds the object (no floor added: "
    "boundary_conditions left out; give a surface_collider there to add one)"
)


def has_region(cfg) -> bool:
    """Whether the config simulates a region of a capture (``scene.region`` or an
    ``objects:`` entry's ``region``)."""
    if cfg.objects is not None:
        return any(o.region is not None for o in cfg.objects)
    return cfg.scene.region is not None


def region_ground(cfg) -> tuple[Any, str] | None:
    """``(cfg with boundary_conditions: [], the ground line)`` when the config has a region
    and leaves ``boundary_conditions`` out (the static scene is the support), else None."""
    if cfg.boundary_conditions is not None or not has_region(cfg):
        return None
    return cfg.model_copy(update={"boundary_conditions": []}), STATIC_GROUND


def static_splats_view(sim_scene, camera, like) -> dict[str, Any] | None:
    """The static splats of ``sim_scene`` for the renderer: ``{means [S, 3] m, covs
    [S, 3, 3] m^2, colors [S, 3], opacities [S]}`` torch tensors of ``like``'s dtype and
    device (colours from their SH as seen from ``camera``), or None without any."""
    static = getattr(sim_scene, "static_splats", None)
    if static is None or static.num == 0:
        return None
    from motionphysics.render.sh import sh_to_rgb

    means = static.means.to(like)
    colors = sh_to_rgb(static.sh.to(like), means - camera.position.to(like)).clamp(0, 1)
    return {
        "means": means,
        "covs": static.covariances().to(like),
        "colors": colors,
        "opacities": static.opacities.to(like),
    }


def static_lines(sim_scene) -> tuple[str | None, str | None]:
    """``(info, warning)`` lines about the static scene of a region run (None, None
    without one): how many static splats there are and how many collide, at what
    resolution, the unseen support filled; and the support warning
    (``SimScene.static_note``) when it is too sparse to hold the object."""
    static = getattr(sim_scene, "static_splats", None)
    if static is None:
        return None, None
    col = getattr(sim_scene, "static_collider", None)
    if col is None:
        info = (
            f"static: {static.num} splats outside scene.region, drawn in every frame; none collide"
        )
    else:
        info = (
            f"static: {static.num} splats outside scene.region, drawn in every frame; "
            f"{col.splats} of them near the grid collide ({col.mode}"
            + (f", friction {col.friction:g}" if col.mode == "frictional" else "")
            + f"; a level set at {col.h:.3g} m)"
        )
        if col.filled:
            info += (
                f"; the support the capture cannot see under the region filled at "
                f"z = {col.fill_height:.4g} m ({col.filled} columns)"
            )
        if col.closed:
            info += f"; {col.closed} columns of gaps in the support closed"
    return info, getattr(sim_scene, "static_note", None)


MIN_RESOLVED_CELLS = 4.0
"""Grid cells along an object's longest extent below which MLS-MPM cannot resolve its
deformation (a body 2 cells across moves as a blob of grid nodes: its squash, wobble and
spread are the grid's, not the material's). About 8 cells is the usual working minimum."""
GOOD_CELLS = 8.0
"""Cells across the object a finer ``sim.grid`` is advised to reach."""


def resolution_line(sim_scene) -> str | None:
    """A warning line when a simulated object spans fewer than :data:`MIN_RESOLVED_CELLS`
    grid cells along its longest extent (None otherwise): how many it spans, at what
    ``dx``, and how much finer ``sim.grid`` would give it about :data:`GOOD_CELLS`."""
    import math

    import numpy as np

    x = np.asarray(sim_scene.particles.detach().cpu().numpy(), dtype=np.float64)
    if x.size == 0:
        return None
    dx = float(sim_scene.dx)
    oid = getattr(sim_scene, "object_id", None)
    ids = np.zeros(len(x), dtype=np.int64) if oid is None else np.asarray(oid.cpu().numpy())
    objs = np.unique(ids)
    span = {int(k): float(np.ptp(x[ids == k], axis=0).max()) / dx for k in objs}
    k = min(span, key=span.get)
    cells = span[k]
    if cells >= MIN_RESOLVED_CELLS:
        return None
    who = "the object" if len(objs) == 1 else f"object {k + 1} of {len(objs)}"
    factor = math.ceil(GOOD_CELLS / max(cells, 1e-6))
    return (
        f"resolution: {who} spans {cells:.1f} grid cells at dx = {dx:.3g} m, too few for "
        f"the simulation to resolve how it deforms (under {MIN_RESOLVED_CELLS:g} cells it "
        f"moves as a blob of grid nodes); a {factor}x finer sim.grid gives it about "
        f"{GOOD_CELLS:g} cells (or give sim.domain close around the motion)"
    )
