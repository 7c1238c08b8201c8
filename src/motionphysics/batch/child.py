"""Entry point of a batch job's process.

``python -m motionphysics.batch.child PARENT_PID ARGS...`` is ``python -m motionphysics
ARGS...`` (the same :func:`motionphysics.cli.main`, the same exit status), in a process
that dies with the batch worker that started it: on Linux it asks the kernel for
SIGKILL when its parent exits (``PR_SET_PDEATHSIG``), so a batch killed outright, or a
Ray worker cancelled, leaves no orphan run writing into a job directory that the next
batch will start again. Elsewhere it is a plain ``motionphysics`` process.

This module must stay tiny: it runs before anything else in the job's process.
"""

from __future__ import annotations

import os
import sys

PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int) -> None:
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    # The parent may have died before prctl took effect: then nobody waits for us.
    if os.getppid() != parent:
        sys.exit(130)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or not argv[0].isdigit():
        print("usage: python -m motionphysics.batch.child PARENT_PID ARGS...", file=sys.stderr)
        return 2
    _die_with_parent(int(argv[0]))
    from motionphysics.cli import main as cli_main

    return cli_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
