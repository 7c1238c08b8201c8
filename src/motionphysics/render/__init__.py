"""Differentiable rendering of Gaussian splats: cameras, rasteriser, deformation hook.

Public API (CONTRACTS.md, "render"): :class:`Camera`, :func:`orbit_camera`,
:func:`camera_from_config`, :func:`load_inria_cameras`, :func:`frame_bounds`,
:func:`rasterize` -> :class:`RenderOutput`, :func:`deform_splats`,
:func:`render_frames`, :func:`sh_to_rgb`. Backends load lazily (Warp kernels on first
CPU render, gsplat on first CUDA render).
"""

from motionphysics.render.camera import (
    Camera,
    camera_from_config,
    frame_bounds,
    load_inria_cameras,
    orbit_camera,
)
from motionphysics.render.deform import deform_splats, polar_rotation, render_frames, render_scene
from motionphysics.render.rasterize import RenderOutput, rasterize
from motionphysics.render.sh import sh_to_rgb

__all__ = [
    "Camera",
    "orbit_camera",
    "camera_from_config",
    "load_inria_cameras",
    "frame_bounds",
    "rasterize",
    "RenderOutput",
    "deform_splats",
    "polar_rotation",
    "render_frames",
    "render_scene",
    "sh_to_rgb",
]
