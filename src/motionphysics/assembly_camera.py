"""The camera and ground phase of the assembly, and the frames it renders.

:func:`default_ground` writes the default floor into a config that leaves
``boundary_conditions`` out (with a ``scene.region``, the static scene is the support
instead: :mod:`motionphysics.assembly_scene`); :func:`resolve_camera` frames the object,
the ground and, given a trajectory, the whole motion; :func:`ground_splats` draws the
ground as a checker floor; :func:`render_view` / :func:`render_frames` draw the splats
following the particles, the ground and the static splats of a region run.
Re-exported by :mod:`motionphysics.assembly`; builds no simulation and writes no file.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from motionphysics.config import RunConfig, SurfaceCollider
from motionphysics.errors import UserInputError

__all__ = [
    "GROUND_FRICTION",
    "default_ground",
    "resolve_camera",
    "ground_splats",
    "render_view",
    "render_frames",
]


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


GROUND_FRICTION = 0.3
"""Coulomb coefficient of the default ground (``sim.boundary.DEFAULT_COLLIDER_FRICTION``)."""


DROP_CUES = ("fall", "bounce")
"""Motion cues of :func:`motionphysics.metrics.adherence.parse_prompt` that need a fall:
a prompt that says one of them ("falls", "is dropped", "hits the ground", "bounces"), not
negated, asks for a drop. (A material word such as "rubber" implies a bounce at half
weight; it asks for no drop.)"""


def _asks_for_a_drop(prompt: str) -> str | None:
    """The prompt's words that ask for a fall or a bounce (None: it asks for neither)."""
    from motionphysics.metrics.adherence import parse_prompt

    cues = parse_prompt(prompt)["cues"]
    for name in DROP_CUES:  # the fall's own words first ("hits the ground", then "bounces")
        for cue in cues:
            if cue["cue"] == name and not cue["negated"]:
                return str(cue["words"])
    return None


def _set_in_motion(cfg: RunConfig) -> bool:
    """Whether the config itself moves the object: an initial velocity or a force."""
    if cfg.forces:
        return True
    vels = [cfg.sim.initial_velocity]
    vels += [o.initial_velocity for o in cfg.objects or [] if o.initial_velocity is not None]
    return any(float(np.abs(np.asarray(v, dtype=np.float64)).max()) > 0.0 for v in vels)


IMPACT_BY = 0.4
"""The default drop lands within this fraction of the simulated time, so the clip shows
the impact and what follows (a 5 m ball dropped its own height takes 1 s to land, longer
than a 20-frame clip)."""


def drop_height(height: float, size: float, duration: float = math.inf, g: float = 9.8) -> float:
    """How far below a resting object the default ground goes when the prompt asks for a
    fall [m]: the object's height ``height``, at least half its largest side ``size`` (a
    flat thing still falls visibly), and at most the fall that lands within
    :data:`IMPACT_BY` of the clip's ``duration`` [s] under gravity ``g`` [m/s^2]."""
    want = max(height, 0.5 * size)
    if math.isfinite(duration) and duration > 0 and g > 0:
        want = min(want, 0.5 * g * (IMPACT_BY * duration) ** 2)
    return float(want)


def default_ground(
    cfg: RunConfig, lowest_z: float, size: float, height: float | None = None
) -> tuple[RunConfig, str | None]:
    """``cfg`` with the default ground when it leaves ``boundary_conditions`` out.

    Left out (null): one frictional ``surface_collider`` facing +z (friction
    :data:`GROUND_FRICTION`) at z = 0 when the scene rests on or above it, else under
    the scene's lowest particle ``lowest_z`` [m] (a scene that reaches below z = 0
    stands on a floor there instead of starting inside one); ``size`` [m] (the scene's
    extent) sets the round-off tolerance. A scene that would stand on that floor while
    the prompt asks for a fall or a bounce ("hits the ground and bounces back"), and that
    the config does not set in motion itself (no initial velocity, no force, gravity
    down), falls onto it instead: the floor goes :func:`drop_height` (``height`` [m], the
    scene's vertical extent) under its lowest point. ``boundary_conditions: []`` is free
    space: no ground. Returns the config with the collider written in (``run.yaml``
    records it) and the summary's ``ground:`` line (None when the config gave its own
    list). With a ``region`` of a capture the static scene is the support and no floor
    is added (:func:`motionphysics.assembly_scene.region_ground`).
    """
    from motionphysics.assembly_scene import region_ground

    by_region = region_ground(cfg)
    if by_region is not None:
        return by_region
    if cfg.boundary_conditions is not None:
        return cfg, None
    z = 0.0 if lowest_z >= -1e-4 * max(size, 1e-6) else float(lowest_z)
    where = (
        "z = 0"
        if z == 0.0
        else f"z = {z:.4g} (under the scene's lowest point, which lies below z = 0)"
    )
    h = float(height) if height is not None else float(size)
    g = np.asarray(cfg.sim.gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    rests = lowest_z - z <= 0.01 * max(h, 1e-6)
    words = _asks_for_a_drop(cfg.prompt) if rests else None
    if words is not None and not _set_in_motion(cfg) and gn > 0 and -g[2] >= 0.7 * gn:
        duration = max(int(cfg.sim.frames) - 1, 1) * float(cfg.sim.frame_dt)
        drop = drop_height(h, size, duration, gn)
        z = float(lowest_z) - drop
        capped = drop < drop_height(h, size) * (1 - 1e-9)
        why = (
            f"; less than its height, to land within the first {100 * IMPACT_BY:.0f} % of "
            "the clip (more `sim.frames` for a higher drop)"
            if capped
            else ""
        )
        where = (
            f"z = {z:.4g}, {drop:.3g} m under the scene's lowest point: the prompt asks for "
            f"a fall ('{words}'), so the object is dropped from there instead of standing "
            f"on the floor{why} (`boundary_conditions` or `scene.translate` for another height)"
        )
    floor = SurfaceCollider(
        type="surface_collider",
        point=(0.0, 0.0, z),
        normal=(0.0, 0.0, 1.0),
        mode="frictional",
        friction=GROUND_FRICTION,
    )
    note = (
        f"ground: frictional floor at {where} (boundary_conditions left out; "
        "`boundary_conditions: []` for free space)"
    )
    return cfg.model_copy(update={"boundary_conditions": [floor]}), note


def _lowest(scene, scene_cfg) -> tuple[float, float, float]:
    """(lowest z [m], largest extent [m], vertical extent [m]) of the splat centres
    ``prepare`` will simulate."""
    from motionphysics.scene.prepare import selected_means

    pts = selected_means(scene, scene_cfg)
    ext = np.ptp(pts, axis=0)
    return float(pts[:, 2].min()), float(ext.max()), float(ext[2])


def _ground_height(cfg: RunConfig, xy_centre: np.ndarray, up: np.ndarray) -> float | None:
    """Height (along ``up``) of the highest upward-facing collider plane under the object."""
    best = None
    for bc in cfg.boundary_conditions or []:
        if isinstance(bc, SurfaceCollider) and bc.mode != "cut":
            n = np.asarray(bc.normal, dtype=np.float64)
            n = n / max(np.linalg.norm(n), 1e-12)
            if float(n @ up) > 0.7:
                # plane n.(p - point) = 0, evaluated under the object's centre
                p0 = np.asarray(bc.point, dtype=np.float64)
                c = xy_centre.copy()
                # move c along up until it is on the plane
                s = float(n @ (p0 - c)) / float(n @ up)
                h = float((c + s * up) @ up)
                best = h if best is None else max(best, h)
    return best


def _up(cfg: RunConfig) -> np.ndarray:
    g = np.asarray(cfg.sim.gravity, dtype=np.float64)
    n = np.linalg.norm(g)
    return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])


def _object_box(sim_scene) -> tuple[np.ndarray, np.ndarray]:
    """Robust bounding box [3], [3] of the visible splat centres [m] (0.5 / 99.5 percentiles)."""
    pts = _np(sim_scene.splats.means).astype(np.float64)
    return np.percentile(pts, 0.5, axis=0), np.percentile(pts, 99.5, axis=0)


def _fit_radius(corners: np.ndarray, cam, fill: float = 0.9) -> float:
    """Smallest orbit radius at which every corner [K, 3] projects inside ``fill`` of the image."""
    import torch

    from motionphysics.render.camera import orbit_camera

    pts = torch.as_tensor(corners, dtype=torch.float64)

    def fits(r: float) -> bool:
        c = orbit_camera(cam.azimuth, cam.elevation, r, cam.look_at, cam.fov, cam.width, cam.height)
        uv, z = c.project(pts)
        if bool((z <= 1e-3).any()):
            return False
        u = (uv[:, 0] - c.cx) / (0.5 * c.width)
        v = (uv[:, 1] - c.cy) / (0.5 * c.height)
        return bool((u.abs() <= fill).all() and (v.abs() <= fill).all())

    lo, hi = 1e-3, 1.0
    while not fits(hi):
        hi *= 2.0
        if hi > 1e7:
            raise UserInputError(
                "camera: could not frame the scene automatically; set camera.radius"
            )
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def resolve_camera(cfg: RunConfig, sim_scene, xs=None) -> tuple[RunConfig, dict[str, Any]]:
    """The run camera; when the config leaves ``radius`` and ``look_at`` unset, frame the scene.

    Auto-framing keeps in view the object and, when there is a ground (the highest
    upward-facing collider plane under the object), the ground below it widened
    sideways by an eighth of the object's size so material spreading on the ground
    stays visible. It searches the orbit radius at which all of that fits in 90 % of
    the image. Without a ground collider the floor of the simulation domain plays the
    ground's part when it is near. Returns the config with the resolved camera written in (so ``run.yaml``
    reproduces the view) and a note for ``params.json``.

    ``xs`` (particle positions [T, P, 3] of a simulated run): frame the whole trajectory
    (the union of every frame's box), so an object that travels stays in the picture.
    """
    cam = cfg.camera
    explicit = cam.model_fields_set
    if cam.camera_file or {"radius", "look_at"} & explicit:
        return cfg, {"framing": "config"}
    lo, hi = _object_box(sim_scene)
    if xs is not None:
        from motionphysics.render.camera import trajectory_bounds

        t_lo, t_hi = (np.asarray(b, dtype=np.float64) for b in trajectory_bounds(_np(xs)))
        lo, hi = np.minimum(lo, t_lo), np.maximum(hi, t_hi)
    up = _up(cfg)
    size = float(np.max(hi - lo))
    box_lo, box_hi = lo.copy(), hi.copy()
    ground = _ground_height(cfg, 0.5 * (lo + hi), up)
    if ground is None and up[2] > 0.99 and np.linalg.norm(cfg.sim.gravity) > 0:
        # No ground collider: a falling object stops at the domain floor; keep it in view
        # when that floor is near (a user-given domain may be far larger than the object).
        wall_lo = sim_scene.wall_lo if sim_scene.wall_lo is not None else sim_scene.domain_lo
        floor = float(_np(wall_lo)[2])
        if lo[2] - floor < 3.0 * size:
            ground = floor
    if ground is not None and abs(up[2]) > 0.99:
        box_lo[2] = min(box_lo[2], ground) if up[2] > 0 else box_lo[2]
        box_hi[2] = box_hi[2] if up[2] > 0 else max(box_hi[2], ground)
        box_lo[:2] -= 0.12 * size
        box_hi[:2] += 0.12 * size
    corners = np.array(
        [
            [x, y, z]
            for x in (box_lo[0], box_hi[0])
            for y in (box_lo[1], box_hi[1])
            for z in (box_lo[2], box_hi[2])
        ]
    )
    look_at = tuple(float(v) for v in 0.5 * (box_lo + box_hi))
    probe = cam.model_copy(update={"look_at": look_at})
    radius = _fit_radius(corners, probe)
    new_cam = cam.model_copy(update={"look_at": look_at, "radius": float(radius)})
    what = "trajectory" if xs is not None else "object"
    return cfg.model_copy(update={"camera": new_cam}), {"framing": f"auto ({what} and ground)"}


def ground_splats(cfg: RunConfig, sim_scene) -> dict[str, Any] | None:
    """Static splats drawing the ground as a grey checker floor (render only; not simulated).

    Drawn when ``camera.show_ground`` is on and a surface collider faces up under the
    object. A square centred below it, of half-side max(1.5 x object size, 1.2 x camera
    radius), checker cells of a sixth of the object's size (at least three splats wide). Returns ``{means [G,3] m, covs [G,3,3] m^2, colors [G,3],
    opacities [G]}`` float32 tensors, or None.
    """
    import torch

    if not getattr(cfg.camera, "show_ground", True):
        return None
    up = _up(cfg)
    if abs(up[2]) < 0.99:
        return None
    lo, hi = _object_box(sim_scene)
    centre = 0.5 * (lo + hi)
    ground = _ground_height(cfg, centre, up)
    if ground is None:
        return None
    size = max(float(np.max(hi - lo)), 1e-3)
    # Wide enough to reach the edges of the view (the camera looks at the object from
    # ``radius`` away), so the floor does not read as a small mat under a distant camera.
    half = max(1.5 * size, 1.2 * float(cfg.camera.radius))
    n = 80
    step = 2 * half / n
    g = (np.arange(n) + 0.5) * step - half
    gx, gy = np.meshgrid(centre[0] + g, centre[1] + g, indexing="ij")
    z = ground - 0.004 * size
    means = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], -1)
    cell = max(size / 6, 3.0 * step)
    parity = (
        np.floor((gx.ravel() - centre[0]) / cell) + np.floor((gy.ravel() - centre[1]) / cell)
    ) % 2
    colors = np.where(parity[:, None] == 0, [0.80, 0.80, 0.78], [0.66, 0.67, 0.66])
    sxy = 0.62 * step
    covs = np.zeros((means.shape[0], 3, 3))
    covs[:, 0, 0] = covs[:, 1, 1] = sxy**2
    covs[:, 2, 2] = (0.002 * size) ** 2
    f32 = torch.float32
    return {
        "means": torch.as_tensor(means, dtype=f32),
        "covs": torch.as_tensor(covs, dtype=f32),
        "colors": torch.as_tensor(colors, dtype=f32),
        "opacities": torch.full((means.shape[0],), 0.98, dtype=f32),
    }


def render_view(sim_scene, x, F, camera, background, ground: dict[str, Any] | None = None):
    """One frame: object splats following particles ``x`` [P,3] m, ``F`` [P,3,3] (+ ground,
    + the static splats of a ``scene.region`` run, unchanged).

    Returns rgb [H, W, 3] float32 in [0, 1] (torch, no autograd needed by callers here).
    """
    import torch

    from motionphysics.render.deform import deform_splats
    from motionphysics.render.rasterize import rasterize

    splats = sim_scene.splats
    x = torch.as_tensor(x, dtype=torch.float32)
    F = torch.as_tensor(F, dtype=torch.float32)
    means, covs, colors = deform_splats(
        splats, x, F, sim_scene.splat_parent.long(), sim_scene.splat_offset.to(x), camera
    )
    opac = splats.opacities.to(x)
    if ground is not None:
        means = torch.cat([means, ground["means"]])
        covs = torch.cat([covs, ground["covs"]])
        colors = torch.cat([colors.clamp(0, 1), ground["colors"]])
        opac = torch.cat([opac, ground["opacities"]])
    from motionphysics.assembly_scene import static_splats_view

    static = static_splats_view(sim_scene, camera, means)
    if static is not None:
        means = torch.cat([means, static["means"]])
        covs = torch.cat([covs, static["covs"]])
        colors = torch.cat([colors, static["colors"]])
        opac = torch.cat([opac, static["opacities"]])
    return rasterize(means, covs, colors, opac, camera, background).rgb


def render_frames(sim_scene, xs, Fs, camera, background, ground, on_frame=None) -> np.ndarray:
    """Render every frame without autograd: x [T,P,3], F [T,P,3,3] -> uint8 [T, H, W, 3]."""
    import torch

    out = []
    with torch.no_grad():
        for i in range(xs.shape[0]):
            rgb = render_view(
                sim_scene,
                torch.as_tensor(xs[i]),
                torch.as_tensor(Fs[i]),
                camera,
                background,
                ground,
            )
            out.append((np.clip(_np(rgb), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
            if on_frame is not None:
                on_frame()
    return np.stack(out)
