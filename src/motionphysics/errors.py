"""Error types that decide the command line's exit status.

``UserInputError`` is bad input a user can fix (exit status 2, one line naming the
file, the field and what was expected). ``OutputError`` is an output the machine
could not write (disk full, I/O error): status 1, one line. Anything else escaping a
command is an internal error (exit status 1, traceback). Never use ``assert`` for
user input.
"""

from __future__ import annotations


class UserInputError(Exception):
    """Bad input: a missing file, a malformed config field, an unknown name.

    The message must be one line that says where (file, field) and what was expected.
    """


class SimulationError(RuntimeError):
    """The simulation diverged or left its valid regime (NaN, runaway velocity).

    Raised with a message naming the frame and the likely cause; the command line
    reports it as bad input (exit 2) since the fix is in the config (time step,
    stiffness, resolution).
    """


class OutputError(Exception):
    """An output could not be written for a reason outside the user's input (a full disk,
    an I/O error, the video encoder dying): exit status 1 with ONE line, no traceback."""


class RunInterrupted(Exception):
    """The user pressed Ctrl-C; the run directory was left consistent and marked partial."""
