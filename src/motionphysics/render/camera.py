"""Pinhole cameras: orbit presets, run-config cameras, a capture's cameras (INRIA
``cameras.json``, nerfstudio ``transforms.json``), moved into the world by the scene
transform.

Conventions (CONTRACTS.md): the world is z-up; camera space is OpenCV (x right,
y down, z forward). A camera-space point ``(x, y, z)`` lands on the continuous pixel
coordinate ``(u, v) = (fx x / z + cx, fy y / z + cy)``; the centre of pixel column
``i`` / row ``j`` sits at ``(i + 0.5, j + 0.5)`` (gsplat's convention), so the image
centre of a ``W x H`` image is ``(W / 2, H / 2)``.

This module only builds cameras; it does not render and imports no heavy packages
beyond torch.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from motionphysics.errors import UserInputError

__all__ = [
    "Camera",
    "orbit_camera",
    "camera_from_config",
    "load_inria_cameras",
    "load_nerfstudio_cameras",
    "load_capture_cameras",
    "transform_camera",
    "frame_bounds",
    "trajectory_bounds",
    "frame_trajectory",
]


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        world_to_cam: rigid transform world -> camera (OpenCV axes), ``[4, 4]``
            float64 tensor, last row ``[0, 0, 0, 1]``.
        fx, fy: focal lengths [pixels].
        cx, cy: principal point [pixels] (continuous coordinates, see module doc).
        width, height: image size [pixels].
    """

    world_to_cam: torch.Tensor
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def rotation(self) -> torch.Tensor:
        """World -> camera rotation ``[3, 3]`` float64 (rows: camera right, down, forward)."""
        return self.world_to_cam[:3, :3]

    @property
    def translation(self) -> torch.Tensor:
        """World -> camera translation ``[3]`` float64 [m]."""
        return self.world_to_cam[:3, 3]

    @property
    def position(self) -> torch.Tensor:
        """Camera centre in world coordinates ``[3]`` float64 [m]."""
        return -self.rotation.T @ self.translation

    @property
    def cam_to_world(self) -> torch.Tensor:
        """Inverse of :attr:`world_to_cam`, ``[4, 4]`` float64."""
        out = torch.eye(4, dtype=torch.float64)
        out[:3, :3] = self.rotation.T
        out[:3, 3] = self.position
        return out

    @property
    def K(self) -> torch.Tensor:  # noqa: N802 (the usual name)
        """Intrinsics matrix ``[3, 3]`` float64."""
        return torch.tensor(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=torch.float64
        )

    def world_to_camera_points(self, points: torch.Tensor) -> torch.Tensor:
        """World points ``[..., 3]`` -> camera-space points ``[..., 3]`` (same dtype)."""
        R = self.rotation.to(points)
        t = self.translation.to(points)
        return points @ R.T + t

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points ``[..., 3]`` -> (pixel coordinates ``[..., 2]``, depth ``[..., 1]``).

        Depth is the camera-space z [m]; points behind the camera get meaningless pixels.
        """
        pc = self.world_to_camera_points(points)
        z = pc[..., 2:3]
        u = self.fx * pc[..., 0:1] / z + self.cx
        v = self.fy * pc[..., 1:2] / z + self.cy
        return torch.cat([u, v], dim=-1), z

    def resized(self, width: int, height: int) -> Camera:
        """Same view at another image size (intrinsics scaled per axis)."""
        sx, sy = width / self.width, height / self.height
        return Camera(
            self.world_to_cam,
            self.fx * sx,
            self.fy * sy,
            self.cx * sx,
            self.cy * sy,
            int(width),
            int(height),
        )


def _look_at_matrix(
    position: torch.Tensor, right: torch.Tensor, forward: torch.Tensor
) -> torch.Tensor:
    down = torch.linalg.cross(forward, right)
    R = torch.stack([right, down, forward])  # rows: camera axes in world coordinates
    out = torch.eye(4, dtype=torch.float64)
    out[:3, :3] = R
    out[:3, 3] = -R @ position
    return out


def _check_size(width: int, height: int, where: str) -> None:
    if int(width) < 1 or int(height) < 1:
        raise UserInputError(
            f"{where}: image width and height must be positive, got {width}x{height}"
        )


def orbit_camera(
    azimuth: float,
    elevation: float,
    radius: float,
    look_at: Sequence[float] = (0.0, 0.0, 0.0),
    fov: float = 45.0,
    width: int = 256,
    height: int = 256,
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> Camera:
    """A camera on a sphere around ``look_at``, looking at it, with ``up`` up in the image.

    Args:
        azimuth: degrees, counter-clockwise about ``up`` from the +x axis (from the
            axis of the world's x projected on the plane normal to ``up`` when ``up``
            is not z).
        elevation: degrees above the plane normal to ``up`` (+-90 look straight down/up;
            the image's "up" then follows the azimuth).
        radius: distance from ``look_at`` [m], > 0.
        look_at: the point looked at, world coordinates [m].
        fov: vertical field of view [degrees], in (0, 180).
        width, height: image size [pixels]. Square pixels: ``fx == fy``.
        up: world up direction (need not be unit).
    """
    if not radius > 0:
        raise UserInputError(f"camera.radius: expected a positive distance, got {radius}")
    if not 0 < fov < 180:
        raise UserInputError(f"camera.fov: expected degrees in (0, 180), got {fov}")
    _check_size(width, height, "camera")
    u = torch.tensor(up, dtype=torch.float64)
    if u.shape != (3,) or float(u.norm()) == 0.0:
        raise UserInputError(f"camera.up: expected a non-zero 3-vector, got {list(up)}")
    u = u / u.norm()
    # In-plane basis (e1, e2, u), right-handed; e1 = world x projected on the plane.
    e1 = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    if abs(float(e1 @ u)) > 0.99:
        e1 = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    e1 = e1 - (e1 @ u) * u
    e1 = e1 / e1.norm()
    e2 = torch.linalg.cross(u, e1)
    az, el = math.radians(azimuth), math.radians(elevation)
    target = torch.tensor(look_at, dtype=torch.float64)
    direction = math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * u
    position = target + radius * direction
    forward = -direction
    # forward x up, written so that it stays defined at elevation +-90 degrees.
    right = -math.sin(az) * e1 + math.cos(az) * e2
    fy = 0.5 * height / math.tan(math.radians(fov) / 2)
    return Camera(
        _look_at_matrix(position, right, forward),
        fy,
        fy,
        width / 2.0,
        height / 2.0,
        int(width),
        int(height),
    )


def frame_bounds(
    lo: Sequence[float],
    hi: Sequence[float],
    azimuth: float = 30.0,
    elevation: float = 20.0,
    fov: float = 45.0,
    width: int = 256,
    height: int = 256,
    margin: float = 1.1,
    radius: float | None = None,
) -> Camera:
    """An orbit camera looking at the centre of a box, far enough to see all of it.

    The box's bounding sphere (times ``margin``) fits inside the narrower of the two
    fields of view. ``radius`` overrides the computed distance.
    """
    lo_t = torch.tensor(lo, dtype=torch.float64)
    hi_t = torch.tensor(hi, dtype=torch.float64)
    centre = 0.5 * (lo_t + hi_t)
    r_sphere = max(float(0.5 * (hi_t - lo_t).norm()), 1e-6) * margin
    half_v = math.radians(fov) / 2
    half_h = math.atan(math.tan(half_v) * width / height)
    if radius is None:
        radius = r_sphere / math.sin(min(half_v, half_h))
    return orbit_camera(azimuth, elevation, radius, centre.tolist(), fov, width, height)


def trajectory_bounds(
    points, lo_percentile: float = 0.5, hi_percentile: float = 99.5, max_points: int = 200_000
) -> tuple[list[float], list[float]]:
    """Box holding an object over a whole trajectory: the union of its per-frame boxes.

    Args:
        points: ``[T, M, 3]`` positions [m] per frame (particles or splat centres;
            numpy, torch or a memory map), or ``[M, 3]`` for one frame.
        lo_percentile, hi_percentile: each frame's box spans these percentiles per
            axis, so a few stray points (ejected material, a bad splat) do not widen it.
        max_points: frames with more points are subsampled with a fixed stride.

    Returns:
        ``(lo [3], hi [3])`` [m]: the smallest box holding every frame's box. The
        automatic camera frames this box (with :func:`frame_bounds`) so that an object
        which moves stays in the picture, not only where it started.
    """
    import numpy as np

    arr = points.detach().cpu().numpy() if hasattr(points, "detach") else points
    if getattr(arr, "ndim", None) == 2:
        arr = arr[None]
    if (
        getattr(arr, "ndim", None) != 3
        or arr.shape[2] != 3
        or arr.shape[0] == 0
        or arr.shape[1] == 0
    ):
        raise ValueError(
            f"points must be [frames, points, 3] with points > 0, got {getattr(arr, 'shape', None)}"
        )
    stride = max(1, -(-int(arr.shape[1]) // int(max_points)))
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for t in range(arr.shape[0]):
        frame = np.asarray(arr[t, ::stride], dtype=np.float64)
        frame = frame[np.isfinite(frame).all(axis=1)]
        if not len(frame):
            continue
        lo = np.minimum(lo, np.percentile(frame, lo_percentile, axis=0))
        hi = np.maximum(hi, np.percentile(frame, hi_percentile, axis=0))
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise ValueError("points hold no finite position")
    return lo.tolist(), hi.tolist()


def frame_trajectory(
    points,
    azimuth: float = 30.0,
    elevation: float = 20.0,
    fov: float = 45.0,
    width: int = 256,
    height: int = 256,
    margin: float = 1.1,
) -> Camera:
    """An orbit camera that sees the object in every frame of ``points [T, M, 3]``.

    :func:`frame_bounds` of :func:`trajectory_bounds`: looks at the centre of the
    box swept by the object and stands far enough for its bounding sphere.
    """
    lo, hi = trajectory_bounds(points)
    return frame_bounds(lo, hi, azimuth, elevation, fov, width, height, margin)


def load_inria_cameras(path: str | Path) -> list[Camera]:
    """Read an INRIA 3DGS ``cameras.json``.

    Each entry has ``id, img_name, width, height, position [3], rotation [3][3], fx, fy``
    where ``rotation`` is the camera-to-world rotation (its columns are the camera's
    OpenCV axes in world coordinates) and ``position`` the camera centre [m]. The
    principal point is the image centre.
    """
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path}: cameras.json not found")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise UserInputError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, list) or not data:
        raise UserInputError(f"{path}: expected a non-empty JSON list of cameras")
    cams = []
    for i, entry in enumerate(data):
        where = f"{path}: camera [{i}]"
        try:
            width, height = int(entry["width"]), int(entry["height"])
            pos = torch.tensor(entry["position"], dtype=torch.float64)
            c2w = torch.tensor(entry["rotation"], dtype=torch.float64)
            fx, fy = float(entry["fx"]), float(entry["fy"])
        except (KeyError, TypeError, ValueError) as err:
            raise UserInputError(
                f"{where}: expected fields width, height, position[3], rotation[3][3], fx, fy ({err!r})"
            ) from None
        if pos.shape != (3,) or c2w.shape != (3, 3):
            raise UserInputError(f"{where}: position must be [3] and rotation [3][3]")
        _check_size(width, height, where)
        if not torch.allclose(c2w @ c2w.T, torch.eye(3, dtype=torch.float64), atol=1e-4):
            raise UserInputError(f"{where}: rotation is not orthonormal")
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = c2w.T
        w2c[:3, 3] = -c2w.T @ pos
        cams.append(Camera(w2c, fx, fy, width / 2.0, height / 2.0, width, height))
    return cams


def load_nerfstudio_cameras(path: str | Path) -> list[Camera]:
    """Read a nerfstudio ``transforms.json`` (also instant-ngp / Blender's layout).

    Intrinsics ``fl_x, fl_y, cx, cy, w, h`` at the top level or per frame (``camera_angle_x``
    when no focal length is given); each frame's ``transform_matrix`` is the camera-to-world
    matrix with OpenGL axes (x right, y up, z backward), turned here into OpenCV axes. The
    transform nerfstudio's data parser applies on top (``dataparser_transforms.json``) is
    not read: the cameras are in the frame the file is in, the frame of a splat file
    exported with them.
    """
    path = Path(path)
    data = _read_json(path, "transforms.json")
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) or not data["frames"]:
        raise UserInputError(f"{path}: expected a JSON object with a non-empty 'frames' list")
    cams = []
    gl_to_cv = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    for i, frame in enumerate(data["frames"]):
        where = f"{path}: frames[{i}]"
        merged = {**data, **frame}  # per-frame intrinsics over the top-level ones

        def get(k, merged=merged):
            return merged.get(k)

        try:
            width, height = int(get("w")), int(get("h"))
            if get("fl_x") is not None:
                fx = float(get("fl_x"))
                fy = float(get("fl_y") if get("fl_y") is not None else fx)
            else:
                fx = fy = 0.5 * width / math.tan(0.5 * float(get("camera_angle_x")))
            cx = float(get("cx")) if get("cx") is not None else width / 2.0
            cy = float(get("cy")) if get("cy") is not None else height / 2.0
            c2w = torch.tensor(frame["transform_matrix"], dtype=torch.float64)
        except (KeyError, TypeError, ValueError) as err:
            raise UserInputError(
                f"{where}: expected w, h, fl_x (or camera_angle_x) and transform_matrix "
                f"[4][4] ({err!r})"
            ) from None
        if c2w.shape not in ((4, 4), (3, 4)):
            raise UserInputError(f"{where}: transform_matrix must be [4][4] or [3][4]")
        _check_size(width, height, where)
        rot = c2w[:3, :3]
        scale = (
            float(torch.linalg.det(rot)) ** (1.0 / 3.0) if float(torch.linalg.det(rot)) > 0 else 0.0
        )
        if not scale > 0 or not torch.allclose(
            rot @ rot.T, (scale**2) * torch.eye(3, dtype=torch.float64), atol=1e-4 * scale**2
        ):
            raise UserInputError(f"{where}: transform_matrix's rotation is not orthonormal")
        r_cv = (rot / scale) @ gl_to_cv  # columns: the OpenCV camera axes in the world
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = r_cv.T
        w2c[:3, 3] = -r_cv.T @ c2w[:3, 3]
        cams.append(Camera(w2c, fx, fy, cx, cy, width, height))
    return cams


def _read_json(path: Path, what: str):
    if not path.is_file():
        raise UserInputError(f"{path}: {what} not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise UserInputError(f"{path}: not valid JSON ({err})") from None


def load_capture_cameras(path: str | Path) -> list[Camera]:
    """The cameras of a capture file: INRIA ``cameras.json`` (a JSON list) or nerfstudio
    ``transforms.json`` (an object with ``frames``), told apart by their content."""
    path = Path(path)
    data = _read_json(path, "camera file")
    if isinstance(data, list):
        return load_inria_cameras(path)
    if isinstance(data, dict) and "frames" in data:
        return load_nerfstudio_cameras(path)
    raise UserInputError(
        f"{path}: not a camera file: expected an INRIA cameras.json (a list of cameras) or "
        "a nerfstudio transforms.json (an object with 'frames')"
    )


def transform_camera(cam: Camera, source_to_world) -> Camera:
    """``cam`` (in a capture's frame) moved by the scene transform ``x_world = s R x + t``
    (``source_to_world`` [4, 4]): the same picture of the transformed scene."""
    m = torch.as_tensor(source_to_world, dtype=torch.float64)
    sr = m[:3, :3]
    s = float(torch.linalg.det(sr)) ** (1.0 / 3.0)
    r = sr / s
    pos = sr @ cam.position + m[:3, 3]
    rot_w2c = cam.rotation @ r.T
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = rot_w2c
    w2c[:3, 3] = -rot_w2c @ pos
    return Camera(w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)


def camera_from_config(cfg, source_to_world=None) -> Camera:
    """The camera of a run config's ``camera`` section (:class:`~motionphysics.config.CameraConfig`).

    With ``from`` (or ``cameras_json``) set, view ``camera_index`` of that file (resized
    to the config's width and height), moved into the world by the scene transform
    ``source_to_world`` [4, 4] (``SimScene.source_to_world``; None: identity);
    otherwise the orbit preset.
    """
    path = getattr(cfg, "camera_file", None) or cfg.cameras_json
    if path:
        cams = load_capture_cameras(path)
        if not 0 <= cfg.camera_index < len(cams):
            raise UserInputError(
                f"camera.camera_index: expected 0..{len(cams) - 1} for {path}, "
                f"got {cfg.camera_index}"
            )
        cam = cams[cfg.camera_index]
        if source_to_world is not None:
            cam = transform_camera(cam, source_to_world)
        return cam.resized(cfg.width, cfg.height)
    return orbit_camera(
        cfg.azimuth, cfg.elevation, cfg.radius, cfg.look_at, cfg.fov, cfg.width, cfg.height
    )
