"""INRIA 3D Gaussian Splatting ``.ply`` files: read and write, losslessly.

Layout (Kerbl et al. 2023, as written by the reference ``GaussianModel.save_ply``):
one ``vertex`` element, binary little endian, float32 properties

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3(K-1)-1}
    opacity  scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

stored pre-activation: ``opacity`` is a logit (sigmoid gives opacity), ``scale_i`` is
the log of a standard deviation, ``rot_*`` an unnormalised quaternion with w first.
``f_rest`` is channel-major: ``f_rest_{c*(K-1) + k}`` is coefficient k+1 of channel c.
The SH degree follows from the f_rest count (0, 9, 24, 45 for degree 0..3).

Reading is by property name, so files with other property orders (Mip-Splatting, no
normals) read too. Writing always uses the reference order above, with zero normals,
so any standard 3DGS viewer opens our files. A float32 round trip is bit-exact.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from motionphysics.errors import UserInputError
from motionphysics.scene.gaussians import GaussianScene, num_sh_coeffs

__all__ = ["read_ply", "read_ply_property", "write_ply", "ply_kind", "REST_COUNTS"]

REST_COUNTS = {0: 0, 1: 9, 2: 24, 3: 45}
"""Number of ``f_rest_*`` properties for each SH degree."""
_DEGREE_OF_REST = {v: k for k, v in REST_COUNTS.items()}
_REQUIRED = (
    ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)


def _open(path: Path):
    from plyfile import PlyData

    if not path.is_file():
        raise UserInputError(f"{path}: file not found")
    try:
        return PlyData.read(str(path))
    except Exception as err:  # plyfile raises several types for malformed headers/bodies
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserInputError(f"{path}: not a readable PLY file ({msg})") from None


def ply_kind(path: str | Path) -> str:
    """``'gaussians'`` for an INRIA 3DGS ply, ``'mesh'`` for a mesh ply (has faces or no f_dc).

    Raises UserInputError for a point cloud that is neither (no faces, no f_dc_*).
    """
    path = Path(path)
    ply = _open(path)
    names = [e.name for e in ply.elements]
    if "face" in names and ply["face"].count > 0:
        return "mesh"
    if "vertex" not in names:
        raise UserInputError(
            f"{path}: PLY has no 'vertex' element; expected 3DGS Gaussians or a mesh"
        )
    props = {p.name for p in ply["vertex"].properties}
    if "f_dc_0" in props:
        return "gaussians"
    raise UserInputError(
        f"{path}: PLY has neither faces (mesh) nor property 'f_dc_0' (3DGS Gaussians); "
        "a bare point cloud cannot be loaded"
    )


def read_ply(path: str | Path) -> GaussianScene:
    """Read an INRIA 3DGS ``.ply`` into a float32 :class:`GaussianScene` (values as stored).

    Raises UserInputError (one line, naming the file and the property) when the file is
    missing, malformed, lacks a needed property, has an f_rest count that is not
    0/9/24/45, or holds NaN/Inf.
    """
    path = Path(path)
    ply = _open(path)
    if "vertex" not in [e.name for e in ply.elements]:
        raise UserInputError(f"{path}: PLY has no 'vertex' element; expected 3DGS Gaussians")
    v = ply["vertex"]
    props = [p.name for p in v.properties]
    present = set(props)
    missing = [p for p in _REQUIRED if p not in present]
    if missing:
        raise UserInputError(
            f"{path}: PLY vertex element lacks propert{'ies' if len(missing) > 1 else 'y'} "
            f"{', '.join(missing)} (expected the INRIA 3DGS layout)"
        )
    rest_names = [p for p in props if p.startswith("f_rest_")]
    n_rest = len(rest_names)
    if n_rest not in _DEGREE_OF_REST:
        raise UserInputError(
            f"{path}: PLY has {n_rest} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0-3)"
        )
    want_rest = [f"f_rest_{i}" for i in range(n_rest)]
    if set(rest_names) != set(want_rest):
        raise UserInputError(
            f"{path}: f_rest_* properties must be numbered f_rest_0..f_rest_{n_rest - 1}"
        )
    degree = _DEGREE_OF_REST[n_rest]
    k = num_sh_coeffs(degree)
    n = v.count
    data = v.data

    def cols(names: list[str]) -> np.ndarray:
        # [n, len(names)] float32; a float64 file is rounded to float32 here.
        return (
            np.stack([np.asarray(data[name], dtype=np.float32) for name in names], axis=1)
            if names
            else np.zeros((n, 0), np.float32)
        )

    means = cols(["x", "y", "z"])
    dc = cols(["f_dc_0", "f_dc_1", "f_dc_2"])  # [n, 3]
    rest = cols(want_rest)  # [n, 3*(k-1)], channel-major
    opacity = cols(["opacity"])[:, 0]
    log_scales = cols(["scale_0", "scale_1", "scale_2"])
    quats = cols(["rot_0", "rot_1", "rot_2", "rot_3"])

    sh = np.empty((n, k, 3), dtype=np.float32)
    sh[:, 0, :] = dc
    if k > 1:
        # rest[:, c*(k-1) + j] -> sh[:, 1 + j, c]
        sh[:, 1:, :] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)

    for name, arr in (
        ("x/y/z", means),
        ("f_dc_*", dc),
        ("f_rest_*", rest),
        ("opacity", opacity),
        ("scale_*", log_scales),
        ("rot_*", quats),
    ):
        bad = ~np.isfinite(arr)
        if bad.any():
            rows = np.nonzero(bad.reshape(n, -1).any(axis=1))[0]
            raise UserInputError(
                f"{path}: property {name} contains NaN or Inf ({rows.size} Gaussians, first at index {rows[0]})"
            )
    zero = np.abs(quats).max(axis=1) == 0  # (not a norm: that overflows for huge values)
    if zero.any():
        raise UserInputError(
            f"{path}: property rot_* has a zero quaternion at index {int(np.argmax(zero))}"
        )

    scene = GaussianScene(
        means=torch.from_numpy(means),
        log_scales=torch.from_numpy(log_scales),
        quats=torch.from_numpy(quats),
        logit_opacities=torch.from_numpy(np.ascontiguousarray(opacity)),
        sh=torch.from_numpy(sh),
    )
    return scene.validate(str(path))


def read_ply_property(path: str | Path, name: str) -> np.ndarray | None:
    """The per-vertex property ``name`` of a ``.ply`` ([N], as stored), or None when the
    file has no such property (e.g. ``simulated`` of a run's ``scene.ply``)."""
    path = Path(path)
    v = _open(path)["vertex"]
    if name not in [p.name for p in v.properties]:
        return None
    return np.asarray(v.data[name])


def _vertex_array(scene: GaussianScene, extra=None) -> np.ndarray:
    n = scene.num
    k = scene.sh.shape[1]
    rest_count = 3 * (k - 1)
    names = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(rest_count)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    sh = scene.sh.detach().cpu().to(torch.float32).numpy()  # [n, k, 3]
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, rest_count)  # channel-major
    flat = np.concatenate(
        [
            scene.means.detach().cpu().to(torch.float32).numpy(),
            np.zeros((n, 3), np.float32),
            sh[:, 0, :],
            rest,
            scene.logit_opacities.detach().cpu().to(torch.float32).numpy()[:, None],
            scene.log_scales.detach().cpu().to(torch.float32).numpy(),
            scene.quats.detach().cpu().to(torch.float32).numpy(),
        ],
        axis=1,
    ).astype("<f4", copy=False)
    extra = dict(extra or {})
    dtype = [(name, "<f4") for name in names] + [
        (k, np.asarray(v).dtype.newbyteorder("<").str) for k, v in extra.items()
    ]
    arr = np.empty(n, dtype=dtype)
    for i, name in enumerate(names):
        arr[name] = flat[:, i]
    for k, v in extra.items():
        if np.asarray(v).shape != (n,):
            raise ValueError(f"write_ply: property {k} has shape {np.shape(v)}, expected ({n},)")
        arr[k] = v
    return arr


def write_ply(scene: GaussianScene, path: str | Path, extra=None) -> Path:
    """Write ``scene`` as an INRIA 3DGS ``.ply`` (reference layout, zero normals).

    ``extra``: more per-splat properties after the reference ones, ``{name: [N] array}``
    (e.g. ``simulated``, uint8), which standard viewers ignore. Written atomically
    (temporary file, then rename). Returns the path.
    """
    from plyfile import PlyData, PlyElement

    path = Path(path)
    scene.validate(f"{path} (scene to write)")
    el = PlyElement.describe(_vertex_array(scene, extra), "vertex")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            PlyData([el], text=False, byte_order="<").write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
