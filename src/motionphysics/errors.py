"""Error types that decide the command line's exit status.

``UserInputError`` is bad input a user can fix (exit status 2, one line naming the
file, the field and what was expected). Anything else escaping a command is an
internal error (exit status 1). Never use ``assert`` for user input.
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


class RunInterrupted(Exception):
    """The user pressed Ctrl-C; the run directory was left consistent and marked partial."""
