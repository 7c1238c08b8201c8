"""A run directory as the viewer reads it: the rest splats, the trajectory, the side data.

What the viewer needs from a run directory (README.md, "Run directory")::

    run.yaml         the resolved config: camera (start view), boundary conditions
    params.json      prompt, material per object with provenance, optimisation history
    trajectory.npz   x [T, P, 3] float32 m, t [T] s, F [T, P, 3, 3] float32,
                     splat_parent [N] int64, splat_offset [N, 3] float32 m
    scene.ply        the prepared rest splats (INRIA layout), N of them, world frame

and, when present, ``log.jsonl`` (loss and parameters per iteration) and
``metrics.json``. A directory that lacks a required file or array is a
:class:`~motionphysics.errors.UserInputError` naming what is missing, with one
exception, for runs written before run directories held ``scene.ply``: when only
``scene.ply`` is missing, the rest splats are rebuilt from run.yaml's scene exactly
as the run prepared them (``load_scene`` + ``prepare``), accepted only if they match
the trajectory's ``splat_parent`` and ``splat_offset``, and the viewer says so.

``x`` and ``F`` are not read whole: ``np.savez`` stores members uncompressed, so each
is memory-mapped in place inside the ``.npz`` and a frame is read when it is asked
for (a compressed file is read whole, once). This module imports no viser and draws
nothing.
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError

__all__ = [
    "REQUIRED_FILES",
    "REQUIRED_ARRAYS",
    "RunData",
    "load_run",
    "npz_member",
]

REQUIRED_FILES = ("run.yaml", "params.json", "trajectory.npz", "scene.ply")
"""Files a directory must hold for the viewer to show it."""
REQUIRED_ARRAYS = ("x", "t", "F", "splat_parent", "splat_offset")
"""Arrays ``trajectory.npz`` must hold (shapes in the module docstring)."""


def npz_member(path: Path, name: str) -> np.ndarray:
    """Array ``name`` of the ``.npz`` at ``path``, memory-mapped when stored uncompressed.

    A ``.npz`` is a zip of ``.npy`` files; an uncompressed (``ZIP_STORED``) member is
    one contiguous ``.npy`` inside the zip, so it can be mapped at its offset.
    Compressed members (``np.savez_compressed``) are read into memory.
    """
    member = f"{name}.npy"
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
        stored = info.compress_type == zipfile.ZIP_STORED
        if stored:
            with open(path, "rb") as fh:
                fh.seek(info.header_offset)
                local = fh.read(30)
                # Local file header: name length at 26, extra length at 28 (little endian).
                n_name = int.from_bytes(local[26:28], "little")
                n_extra = int.from_bytes(local[28:30], "little")
                start = info.header_offset + 30 + n_name + n_extra
                fh.seek(start)
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
                else:
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
                offset = fh.tell()
            if dtype.hasobject:
                raise UserInputError(f"{path}: array '{name}' holds Python objects")
            if math.prod(shape) == 0:
                return np.zeros(shape, dtype)
            return np.memmap(
                path, dtype=dtype, mode="r", offset=offset, shape=shape,
                order="F" if fortran else "C",
            )  # fmt: skip
        with zf.open(member) as fh:
            return np.lib.format.read_array(fh, allow_pickle=False)


@dataclass
class RunData:
    """One run directory, loaded for viewing (large arrays memory-mapped).

    Attributes:
        path: the run directory.
        name: a short label (the directory name).
        config: the run's :class:`~motionphysics.config.RunConfig` (from run.yaml).
        params: params.json as a dict.
        splats: rest :class:`~motionphysics.scene.gaussians.GaussianScene`, N splats.
        x: ``[T, P, 3]`` float32 particle positions [m] (memory-mapped).
        F: ``[T, P, 3, 3]`` float32 deformation gradients (memory-mapped).
        t: ``[T]`` frame times [s].
        parent: ``[N]`` int64 particle each splat follows.
        offset: ``[N, 3]`` float32 rest offset splat - parent [m].
        log: records of ``log.jsonl`` (empty when the run was not optimised).
        metrics: metrics.json (empty dict when absent).
        static: the static splats of a ``scene.region`` run, or None.
    """

    path: Path
    name: str
    config: Any
    params: dict[str, Any]
    splats: Any
    x: np.ndarray
    F: np.ndarray
    t: np.ndarray
    parent: np.ndarray
    offset: np.ndarray
    log: list[dict[str, Any]] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    static: Any = None
    """The static splats of a ``scene.region`` run (scene.ply's splats whose ``simulated``
    flag is 0), drawn unchanged in every frame; None for other runs."""

    @property
    def num_frames(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_splats(self) -> int:
        return int(self.parent.shape[0])

    @property
    def frame_dt(self) -> float:
        """Seconds between frames (from ``t``; the config's ``sim.frame_dt`` for one frame)."""
        if self.t.shape[0] > 1:
            return float(self.t[1] - self.t[0])
        return float(self.config.sim.frame_dt)

    @property
    def prompt(self) -> str:
        return str(self.params.get("prompt") or self.config.prompt)

    def history(self) -> list[dict[str, Any]]:
        """Optimisation records: ``log.jsonl`` when present, else params.json's ``history``."""
        return list(self.log) or list(self.params.get("history") or [])


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserInputError(f"{path}: not readable JSON ({err})") from None


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    out = []
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except ValueError:
            break  # a torn last line of a killed run: keep what came before
        if isinstance(rec, dict):
            out.append(rec)
    return out


def _rebuild_splats(path: Path, config, parent: np.ndarray, offset: np.ndarray):
    """Rest splats of a run without scene.ply, prepared again from its run.yaml."""
    from motionphysics.scene import load_scene, prepare

    scene = load_scene(config.scene.source, shade=config.scene.shade)
    sim_scene = prepare(
        scene,
        config.scene,
        config.sim,
        list(config.boundary_conditions or []),
        forces=list(config.forces),
        material_class=config.material.class_,
    )
    par = sim_scene.splat_parent.detach().cpu().numpy()
    off = sim_scene.splat_offset.detach().cpu().numpy()
    if (
        par.shape != parent.shape
        or not np.array_equal(par, parent)
        or not np.allclose(off, offset, atol=1e-5)
    ):
        raise UserInputError(
            f"{path}: missing scene.ply, and the splats prepared again from run.yaml's "
            f"scene.source ({config.scene.source}) do not match trajectory.npz's splat_parent"
        )
    return sim_scene.splats


def object_index(npz: Path, name: str) -> tuple[np.ndarray, list[str]]:
    """``(object_id [P] int64, object names)`` of a trajectory of several objects, and
    the one-line error when ``name`` is not one of them (or the run has one object)."""
    with np.load(npz, allow_pickle=False) as z:
        if "object_id" not in z.files:
            raise UserInputError(
                f"--object {name}: {npz.parent} holds one object (no objects: in its config)"
            )
        oid = np.asarray(z["object_id"]).astype(np.int64).reshape(-1)
        names = [str(n) for n in z["object_names"]] if "object_names" in z.files else []
    if name not in names:
        raise UserInputError(
            f"--object {name}: not an object of {npz.parent}; expected one of {', '.join(names)}"
        )
    return oid, names


def load_run(
    path: str | Path, notes: list[str] | None = None, object_name: str | None = None
) -> RunData:
    """Open a run directory for viewing; a directory that is not a run is a one-line error.

    ``notes`` (when given) receives one line per thing the viewer had to do that a
    person should know (e.g. rest splats rebuilt because scene.ply is missing).
    ``object_name``: a run of several objects shows only that object's splats (the
    splats whose particle belongs to it, trajectory.npz ``object_id``).
    """
    from motionphysics.config import load_config
    from motionphysics.scene.ply import read_ply

    path = Path(path)
    if not path.is_dir():
        raise UserInputError(f"{path}: not a run directory (no such directory)")
    missing = [f for f in REQUIRED_FILES if not (path / f).is_file()]
    rebuild = missing == ["scene.ply"]
    static = None
    if missing and not rebuild:
        raise UserInputError(
            f"{path}: not a viewable run directory: missing {', '.join(missing)} "
            f"(a run holds {', '.join(REQUIRED_FILES)})"
        )
    npz = path / "trajectory.npz"
    try:
        with zipfile.ZipFile(npz) as zf:
            members = {n[:-4] for n in zf.namelist() if n.endswith(".npy")}
    except (OSError, zipfile.BadZipFile) as err:
        raise UserInputError(f"{npz}: not a readable .npz trajectory ({err})") from None
    lacking = [a for a in REQUIRED_ARRAYS if a not in members]
    if lacking:
        raise UserInputError(
            f"{npz}: missing array{'s' if len(lacking) > 1 else ''} {', '.join(lacking)} "
            f"(the viewer needs {', '.join(REQUIRED_ARRAYS)})"
        )
    try:
        arrays = {a: npz_member(npz, a) for a in REQUIRED_ARRAYS}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise UserInputError(f"{npz}: not a readable .npz trajectory ({err})") from None
    x, F, t = arrays["x"], arrays["F"], np.asarray(arrays["t"], dtype=np.float64)
    parent = np.asarray(arrays["splat_parent"]).astype(np.int64)
    offset = np.array(arrays["splat_offset"], dtype=np.float32)  # small: a copy
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[0] < 1:
        raise UserInputError(f"{npz}: x must be [frames, particles, 3], got {x.shape}")
    T, P = int(x.shape[0]), int(x.shape[1])
    if F.shape != (T, P, 3, 3):
        raise UserInputError(f"{npz}: F must be {[T, P, 3, 3]} like x, got {list(F.shape)}")
    if t.shape != (T,):
        raise UserInputError(f"{npz}: t must be [{T}], got {list(t.shape)}")
    config = load_config(path / "run.yaml")
    if rebuild:
        splats = _rebuild_splats(path, config, parent, offset)
        if notes is not None:
            notes.append(
                f"{path}: no scene.ply; rest splats prepared again from run.yaml's scene "
                f"({config.scene.source}), matching the trajectory's splat_parent"
            )
    else:
        from motionphysics.scene.ply import read_ply_property

        splats = read_ply(path / "scene.ply")
        flag = read_ply_property(path / "scene.ply", "simulated")
        if flag is not None:
            # scene.region: the simulated splats first, then the static scene (flag 0)
            import torch

            sim = np.asarray(flag) != 0
            static = splats.subset(torch.from_numpy(np.nonzero(~sim)[0]))
            splats = splats.subset(torch.from_numpy(np.nonzero(sim)[0]))
    N = splats.num
    if parent.shape != (N,) or offset.shape != (N, 3):
        raise UserInputError(
            f"{npz}: splat_parent [{N}] and splat_offset [{N}, 3] must match the {N} splats "
            f"of scene.ply, got {list(parent.shape)} and {list(offset.shape)}"
        )
    if N and (parent.min() < 0 or parent.max() >= P):
        raise UserInputError(f"{npz}: splat_parent indexes particles outside 0..{P - 1}")
    if object_name is not None:
        import torch

        oid, names = object_index(npz, object_name)
        keep = np.nonzero(oid[parent] == names.index(object_name))[0]
        splats = splats.subset(torch.from_numpy(keep))
        parent, offset = parent[keep], offset[keep]
    params = _read_json(path / "params.json")
    if not isinstance(params, dict):
        raise UserInputError(f"{path / 'params.json'}: expected a JSON object")
    log = _read_jsonl(path / "log.jsonl") if (path / "log.jsonl").is_file() else []
    metrics = _read_json(path / "metrics.json") if (path / "metrics.json").is_file() else {}
    return RunData(
        path=path,
        name=path.resolve().name,
        config=config,
        params=params,
        splats=splats,
        x=x,
        F=F,
        t=t,
        parent=parent,
        offset=offset,
        log=log,
        metrics=metrics if isinstance(metrics, dict) else {},
        static=static,
    )
