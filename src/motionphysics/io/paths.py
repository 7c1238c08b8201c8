"""Checked output locations: one line (status 2) for an output path a user cannot write.

Every command that writes a file a user named goes through :func:`check_output_file`
BEFORE doing the work, so a typo in ``--out`` costs nothing and never ends in a
traceback from deep inside a writer; :func:`writing` turns what still fails while
writing (a full disk, a broken ffmpeg pipe) into one line (status 1) and removes the
partial file. Missing parent folders are never created here: a file path whose folder
does not exist is refused (``render --out /nonexist/x.png`` must not create ``/nonexist``).

This module must not write outputs itself; the run-directory writer has its own rules.
"""

from __future__ import annotations

import errno
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from motionphysics.errors import OutputError, UserInputError

__all__ = ["check_output_file", "check_output_folder", "writing", "USER_ERRNOS"]

USER_ERRNOS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR, errno.ENOENT}
"""Errors of the location itself (fix: another path): status 2. Others (ENOSPC, EIO): 1."""


def _why(err: OSError) -> str:
    return {
        errno.EACCES: "permission denied",
        errno.EPERM: "permission denied",
        errno.EROFS: "read-only file system",
        errno.ENOSPC: "no space left on the device",
        errno.EDQUOT: "disk quota exceeded",
    }.get(err.errno, err.strerror or type(err).__name__)


def check_output_folder(folder: str | Path, flag: str, shown: str | None = None) -> Path:
    """An existing folder the process can create files in, else one-line UserInputError."""
    folder = Path(folder)
    shown = shown or str(folder)
    if not folder.exists():
        raise UserInputError(
            f"{flag} {shown}: the folder {folder} does not exist (create it first)"
        )
    if not folder.is_dir():
        raise UserInputError(f"{flag} {shown}: {folder} is not a folder")
    try:
        # os.access is not enough (root, ACLs, read-only mounts): really create a file.
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".motionphysics-probe-"):
            pass
    except OSError as err:
        if err.errno in USER_ERRNOS:
            raise UserInputError(
                f"{flag} {shown}: cannot write in {folder} ({_why(err)})"
            ) from None
        raise OutputError(f"{flag} {shown}: cannot write in {folder} ({_why(err)})") from None
    return folder


def check_output_file(path: str | Path, flag: str = "--out") -> Path:
    """A file path whose folder exists and is writable, and which is not a folder."""
    p = Path(path)
    if str(path).endswith(os.sep) or p.is_dir():
        raise UserInputError(f"{flag} {path}: is a folder; expected a file name")
    check_output_folder(p.parent if str(p.parent) else Path("."), flag, str(path))
    if p.exists() and not os.access(p, os.W_OK):
        raise UserInputError(f"{flag} {path}: the file exists and is not writable")
    return p


@contextmanager
def writing(path: str | Path, flag: str = "--out", partial: str | Path | None = None):
    """Context of writing ``path``: OSError (and an ffmpeg broken pipe) become one line.

    A location error is :class:`UserInputError` (status 2); anything else (disk full,
    I/O error, ffmpeg dying) :class:`OutputError` (status 1). ``partial``: a temporary
    file the writer uses, removed on failure so nothing half-written is left.
    """
    try:
        yield Path(path)
    except (OSError, RuntimeError, ValueError) as err:
        if partial is not None:
            try:
                Path(partial).unlink()
            except OSError:
                pass
        if isinstance(err, BrokenPipeError) or "broken pipe" in str(err).lower():
            raise OutputError(
                f"{flag} {path}: the video encoder (ffmpeg) stopped while writing (broken pipe); "
                "check that the folder is writable and has space"
            ) from None
        if isinstance(err, OSError):
            cls = UserInputError if err.errno in USER_ERRNOS else OutputError
            raise cls(f"{flag} {path}: could not write ({_why(err)})") from None
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
        raise OutputError(f"{flag} {path}: could not write ({first})") from None
