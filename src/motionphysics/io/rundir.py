"""The run directory: one folder per run, every file written atomically.

Layout (README, "Run directory")::

    run.yaml  params.json  trajectory.npz  video.mp4  scene.ply  splats/  log.jsonl
    metrics.json  plots/  checkpoint.pt  report.html

Every file is written to a temporary name in the same folder and moved into place
with ``os.replace``, so a reader (or a run killed half-way) sees either the old file
or the new one, never a torn one. ``log.jsonl`` is appended line by line and flushed.
A write that fails for a reason of the machine (a full disk, an I/O error, the video
encoder dying) removes its temporary file, leaves the previous files as they were and
raises :class:`~motionphysics.errors.OutputError` (exit 1, one line naming the file);
a location the user cannot write (permission, read-only) is a UserInputError (exit 2).

A directory that already holds a run is refused unless the caller asks to resume it
or to overwrite it (``--force`` deletes only the files a run writes, never anything
else). Whether a run finished is recorded in ``params.json`` (``partial``); this
module reads it back but does not decide it.

This module knows file names and formats, not what a simulation is.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import OutputError, UserInputError

__all__ = [
    "RUN_FILES",
    "RUN_DIRS",
    "RunDirectory",
    "atomic_write",
    "output_errors",
    "write_trajectory",
    "read_trajectory",
    "TRAJECTORY_KEYS",
]

RUN_FILES = (
    "run.yaml",
    "params.json",
    "trajectory.npz",
    "video.mp4",
    "log.jsonl",
    "metrics.json",
    "checkpoint.pt",
    "report.html",
    "scene.ply",
    "video_initial.mp4",
    "prior_reference.mp4",
)
"""Files a run writes (the ones ``--force`` may delete)."""
RUN_DIRS = ("splats", "plots")
"""Sub-folders a run writes (the ones ``--force`` may delete)."""

TRAJECTORY_KEYS = ("x", "t", "det_F")
"""Keys every ``trajectory.npz`` holds; see :func:`write_trajectory` for the rest."""


def _reason(err: BaseException, folder: Path) -> str:
    """Why a write failed, in words (``no space left on the device`` ...).

    Library writers (ffmpeg through imageio, torch) often lose the errno; a folder whose
    file system has no free block is then still named as full."""
    from motionphysics.io.paths import _why

    if isinstance(err, OSError) and err.errno is not None:
        return _why(err)
    try:
        st = os.statvfs(folder)
        if st.f_bavail == 0:
            return "no space left on the device"
    except OSError:
        pass
    if isinstance(err, BrokenPipeError) or "broken pipe" in str(err).lower():
        return "the video encoder (ffmpeg) stopped (broken pipe)"
    first = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return first[:200]


@contextmanager
def output_errors(path: str | Path, *, library: bool = False) -> Iterator[None]:
    """Turn a failed write of ``path`` into one line.

    OSError of the location (permission, read-only file system): UserInputError (exit
    2). Any other OSError (ENOSPC, EDQUOT, EIO, EFBIG ...), and with ``library`` a
    RuntimeError / ValueError of a library writer (ffmpeg, matplotlib, torch):
    OutputError (exit 1). The message names the file and says the run directory keeps
    what was written before.
    """
    from motionphysics.io.paths import USER_ERRNOS

    path = Path(path)
    kinds: tuple[type[BaseException], ...] = (
        (OSError, RuntimeError, ValueError) if library else (OSError,)
    )
    try:
        yield
    except kinds as err:
        why = _reason(err, path.parent)
        if isinstance(err, OSError) and err.errno in USER_ERRNOS:
            raise UserInputError(f"{path}: cannot write ({why}); choose another --out") from None
        raise OutputError(
            f"{path}: could not write ({why}); the files written before it are intact "
            "(params.json says partial); make room and rerun with --resume"
        ) from None


@contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary sibling of ``path`` for writing; move it into place on success.

    On any exception (Ctrl-C included) the temporary file is removed and ``path``
    keeps its previous content; an OSError of writing becomes an OutputError /
    UserInputError (:func:`output_errors`).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with output_errors(path):
        f = open(tmp, mode)  # noqa: SIM115 - closed below on every path
        try:
            yield f
            f.flush()
            os.fsync(f.fileno())
            f.close()
            os.replace(tmp, path)
        except BaseException:
            try:
                f.close()  # may raise again (ENOSPC on the final flush)
            except OSError:
                pass
            tmp.unlink(missing_ok=True)
            raise


@contextmanager
def _atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path to write with a library (ffmpeg, matplotlib); then replace."""
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    with output_errors(path, library=True):
        try:
            yield tmp
            if not tmp.exists():
                raise RuntimeError(f"{path}: the writer produced no file")
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            # io.video writes its own ``.<stem>.partial<suffix>`` beside the temporary
            for partial in path.parent.glob(f".{tmp.stem}.partial*"):
                partial.unlink(missing_ok=True)
            raise


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    try:  # torch tensors without importing torch here
        return obj.detach().cpu().tolist()
    except AttributeError:
        pass
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _finite(obj: Any) -> Any:
    """Replace NaN/inf floats by None: JSON has no such numbers and readers choke on them."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def to_json_text(obj: Any) -> str:
    """JSON text of ``obj`` (numpy scalars/arrays allowed; NaN and inf become null)."""
    plain = json.loads(json.dumps(obj, default=_json_default))
    return json.dumps(_finite(plain), indent=2, allow_nan=False) + "\n"


class RunDirectory:
    """A run's output folder.

    Parameters
    ----------
    path:
        The folder; created (with parents) if missing.
    resume:
        Accept a folder that already holds a run and keep its files (the caller
        continues it).
    force:
        Accept a folder that already holds a run and delete the files a run writes
        (``RUN_FILES``, ``RUN_DIRS``) before starting; other files are left alone.
        With ``force`` a non-empty folder that holds no run is also accepted.
    create:
        ``False`` opens an existing run read-mostly (``motionphysics eval``): the
        folder must hold a run; nothing is deleted.
    """

    def __init__(
        self, path: str | Path, *, resume: bool = False, force: bool = False, create: bool = True
    ):
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise UserInputError(
                f"{self.path}: exists and is not a directory; choose another --out"
            )
        if not create:
            if not self.holds_run(self.path):
                raise UserInputError(
                    f"{self.path}: not a run directory (expected params.json or trajectory.npz)"
                )
            return
        if self.path.exists():
            has_run = self.holds_run(self.path)
            others = [p for p in self.path.iterdir() if not p.name.startswith(".")]
            if has_run and not (resume or force):
                state = "a partial run" if self.is_partial(self.path) else "another run"
                raise UserInputError(
                    f"{self.path}: holds {state}; pass --resume to continue it, --force to "
                    "overwrite it, or choose another --out"
                )
            if not has_run and others and not force:
                raise UserInputError(
                    f"{self.path}: not empty and holds no run; choose another --out "
                    "(or pass --force to write into it)"
                )
            if force and not resume:
                self.clear()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise UserInputError(
                f"{self.path}: cannot create the run directory ({err.strerror})"
            ) from None
        if not os.access(self.path, os.W_OK):
            raise UserInputError(f"{self.path}: the run directory is not writable")

    # -- state ---------------------------------------------------------------------------
    @staticmethod
    def holds_run(path: str | Path) -> bool:
        """True when ``path`` holds any file a run writes."""
        path = Path(path)
        return path.is_dir() and any((path / name).exists() for name in RUN_FILES)

    @staticmethod
    def is_partial(path: str | Path) -> bool:
        """True when the run at ``path`` did not finish (``params.json`` says so or is missing)."""
        params = Path(path) / "params.json"
        if not params.is_file():
            return True
        try:
            return bool(json.loads(params.read_text()).get("partial", True))
        except (OSError, ValueError):
            return True

    def clear(self) -> None:
        """Delete the files and folders a run writes (and stale temporaries); nothing else."""
        for name in RUN_FILES:
            (self.path / name).unlink(missing_ok=True)
        for name in RUN_DIRS:
            shutil.rmtree(self.path / name, ignore_errors=True)
        for tmp in self.path.glob(".*tmp-*"):
            tmp.unlink(missing_ok=True)
        for tmp in self.path.glob(".tmp-*"):
            tmp.unlink(missing_ok=True)

    def file(self, name: str) -> Path:
        """Path of a file in the run (sub-folders created)."""
        p = self.path / name
        with output_errors(p):
            p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def clean_temporaries(self) -> list[str]:
        """Remove temporaries a killed process left (``.NAME.tmp-PID``, ``.tmp-PID-NAME``,
        ``.STEM.partial.EXT``); a resumed run starts from the finished files only."""
        gone = []
        for pattern in (".*tmp-*", ".tmp-*", ".*.partial*"):
            for tmp in self.path.glob(pattern):
                if tmp.is_file():
                    tmp.unlink(missing_ok=True)
                    gone.append(tmp.name)
        return gone

    def exists(self, name: str) -> bool:
        return (self.path / name).exists()

    # -- writers -------------------------------------------------------------------------
    def write_bytes(self, name: str, data: bytes) -> Path:
        p = self.file(name)
        with atomic_write(p, "wb") as f:
            f.write(data)
        return p

    def write_text(self, name: str, text: str) -> Path:
        return self.write_bytes(name, text.encode("utf-8"))

    def write_json(self, name: str, obj: Any) -> Path:
        """Write JSON (indented; numpy values converted; NaN/inf written as null)."""
        return self.write_text(name, to_json_text(obj))

    def write_yaml(self, name: str, obj: Any) -> Path:
        import yaml

        plain = json.loads(to_json_text(obj))
        return self.write_text(name, yaml.safe_dump(plain, sort_keys=False))

    @contextmanager
    def writing(self, name: str) -> Iterator[Path]:
        """Hand a temporary path to a library writer; it replaces ``name`` on success."""
        with _atomic_path(self.file(name)) as tmp:
            yield tmp

    def append_jsonl(self, name: str, record: Mapping[str, Any]) -> None:
        """Append one JSON line and flush it to disk (a crash loses at most this line)."""
        line = json.dumps(
            _finite(json.loads(json.dumps(record, default=_json_default))), allow_nan=False
        )
        p = self.file(name)
        with output_errors(p), open(p, "a", encoding="utf-8") as f:
            f.write(line + "\n")
            f.flush()
            os.fsync(f.fileno())

    # -- readers -------------------------------------------------------------------------
    def read_json(self, name: str) -> Any:
        p = self.path / name
        try:
            return json.loads(p.read_text())
        except FileNotFoundError:
            raise UserInputError(f"{p}: missing from the run directory") from None
        except ValueError as err:
            raise UserInputError(f"{p}: not valid JSON ({err})") from None

    def read_jsonl(self, name: str) -> list[dict[str, Any]]:
        p = self.path / name
        if not p.is_file():
            return []
        out = []
        for line in p.read_text().splitlines():
            line = line.strip()
            if not line:
                continue
            try:
                out.append(json.loads(line))
            except ValueError:
                break  # a torn last line of a killed run: keep what came before
        return out


def write_trajectory(
    path: str | Path, *, x: np.ndarray, t: np.ndarray, F: np.ndarray | None = None, **extra: Any
) -> Path:
    """Write ``trajectory.npz`` atomically.

    Parameters
    ----------
    x: float32 [T, P, 3]
        World positions of the simulated particles per output frame [m].
    t: float32 [T]
        Time of each frame [s] (frame 0 is the initial state, t = 0).
    F: float32 [T, P, 3, 3], optional
        Deformation gradient per particle and frame [-]. When given, ``F`` and
        ``det_F`` [T, P] (volume ratio) are stored.
    extra:
        Further arrays (``mass [P]`` kg, ``volume [P]`` m^3, ``splat_parent [N]``,
        ``splat_offset [N, 3]`` m, ``gravity [3]`` m/s^2, ``domain_lo/hi [3]`` m ...),
        stored as given (floats as float32 unless they are already float64 scalars).
    """
    x = np.asarray(x, dtype=np.float32)
    t = np.asarray(t, dtype=np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"x must be [frames, particles, 3], got {x.shape}")
    if t.shape != (x.shape[0],):
        raise ValueError(f"t must be [frames]={x.shape[0]}, got {t.shape}")
    arrays: dict[str, np.ndarray] = {"x": x, "t": t}
    if F is not None:
        F = np.asarray(F, dtype=np.float32)
        if F.shape != (*x.shape[:2], 3, 3):
            raise ValueError(f"F must be {(*x.shape[:2], 3, 3)}, got {F.shape}")
        arrays["F"] = F
        arrays["det_F"] = np.linalg.det(F.astype(np.float64)).astype(np.float32)
    for key, value in extra.items():
        a = np.asarray(value)
        if a.dtype.kind == "f" and a.dtype != np.float32:
            a = a.astype(np.float32)
        arrays[key] = a
    path = Path(path)
    with atomic_write(path, "wb") as f:
        np.savez(f, **arrays)
    return path


def read_trajectory(path: str | Path) -> dict[str, np.ndarray]:
    """Read ``trajectory.npz`` into a dict of arrays; a bad file is a one-line user error."""
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path}: missing (the run has no trajectory; did it finish?)")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise UserInputError(f"{path}: not a readable .npz trajectory ({err})") from None
    for key in ("x", "t"):
        if key not in data:
            raise UserInputError(
                f"{path}: no array '{key}' (expected x [frames, particles, 3], t [frames])"
            )
    x = data["x"]
    if x.ndim != 3 or x.shape[2] != 3 or data["t"].shape != (x.shape[0],):
        raise UserInputError(
            f"{path}: expected x [frames, particles, 3] and t [frames], got x {x.shape}, t {data['t'].shape}"
        )
    return data
