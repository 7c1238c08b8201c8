"""Progress display and stage timing for long commands.

One :class:`Progress` object follows a command through its stages ("load scene",
"simulate", ...). On a terminal it draws a rich progress bar (stage name, a bar for
stages with a known amount of work, elapsed time); in a pipe it stays quiet, so logs
and scripted runs see only the final summary. ``--quiet`` silences it everywhere;
``--verbose`` also prints one line per finished stage to stderr (even in a pipe).

Every stage is timed whatever the display does: ``Progress.timings`` maps a stage
name to wall seconds, and the pipeline writes it to ``params.json`` and the report.
This module must not import torch or warp: it is used before they load.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import IO

from motionphysics.events import Observer

__all__ = ["Progress", "ProgressObserver", "Stage"]


class Stage:
    """Handle of a running stage: ``advance(n)`` moves its bar; ``total`` may be set late."""

    def __init__(self, progress: Progress, name: str, total: int | None):
        self._progress = progress
        self.name = name
        self.total = total
        self.done = 0

    def set_total(self, total: int) -> None:
        self.total = int(total)
        self._progress._update(self)

    def advance(self, n: int = 1) -> None:
        self.done += int(n)
        self._progress._update(self)

    def note(self, text: str) -> None:
        """Replace the stage's description (e.g. ``simulate (frame 12, 3.1 s)``)."""
        self._progress._describe(self, text)


class Progress:
    """Stage timer with an optional rich display.

    Parameters
    ----------
    quiet:
        No display at all (``--quiet``).
    verbose:
        Print one line per finished stage to ``stream`` even when it is not a terminal.
    stream:
        Where the display goes (default ``sys.stderr``); the display is drawn only
        when this is a terminal.
    """

    def __init__(self, quiet: bool = False, verbose: bool = False, stream: IO[str] | None = None):
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = bool(quiet)
        self.verbose = bool(verbose) and not self.quiet
        isatty = getattr(self.stream, "isatty", None)
        self.interactive = (not self.quiet) and bool(isatty and isatty())
        self.timings: dict[str, float] = {}
        """Wall seconds per finished (or interrupted) stage, in the order they ran."""
        self._rich = None
        self._task = None
        self._t0 = time.perf_counter()

    # -- lifecycle ---------------------------------------------------------------------
    def __enter__(self) -> Progress:
        if self.interactive:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                SpinnerColumn,
                TextColumn,
                TimeElapsedColumn,
            )
            from rich.progress import Progress as RichProgress

            self._rich = RichProgress(
                SpinnerColumn(),
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=Console(file=self.stream),
                transient=False,
            )
            self._rich.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._rich is not None:
            self._rich.stop()
            self._rich = None

    @property
    def elapsed(self) -> float:
        """Seconds since this object was created."""
        return time.perf_counter() - self._t0

    # -- stages ------------------------------------------------------------------------
    @contextmanager
    def stage(self, name: str, total: int | None = None) -> Iterator[Stage]:
        """Time a stage; on a terminal show it with a bar when ``total`` is known.

        The time is recorded even when the stage raises (an interrupted run still
        reports how long each stage took). Repeated names accumulate.
        """
        st = Stage(self, name, total)
        if self._rich is not None:
            self._task = self._rich.add_task(name, total=total)
        t0 = time.perf_counter()
        ok = False
        try:
            yield st
            ok = True
        finally:
            dt = time.perf_counter() - t0
            self.timings[name] = self.timings.get(name, 0.0) + dt
            if self._rich is not None and self._task is not None:
                if total is not None or st.total is not None:
                    self._rich.update(self._task, completed=st.total or st.done)
                else:
                    self._rich.update(self._task, total=1, completed=1)
                self._rich.update(self._task, description=f"{name} ({dt:.1f} s)")
                self._task = None
            if self.verbose and self._rich is None:
                status = "done" if ok else "stopped"
                print(f"[{self.elapsed:7.1f} s] {name}: {status} in {dt:.2f} s", file=self.stream)

    def log(self, text: str) -> None:
        """A detail line: shown with ``--verbose`` only."""
        if not self.verbose:
            return
        if self._rich is not None:
            self._rich.console.print(text)
        else:
            print(text, file=self.stream)

    def _update(self, st: Stage) -> None:
        if self._rich is not None and self._task is not None:
            self._rich.update(self._task, total=st.total, completed=st.done)

    def _describe(self, st: Stage, text: str) -> None:
        if self._rich is not None and self._task is not None:
            self._rich.update(self._task, description=text)


class ProgressObserver(Observer):
    """The :class:`~motionphysics.events.Observer` side of a :class:`Progress`: messages
    become detail lines of the display (stages are timed by :meth:`Progress.stage`,
    which the run-directory writer opens itself)."""

    def __init__(self, progress: Progress):
        self.progress = progress

    def message(self, level: str, text: str) -> None:
        self.progress.log(text if level == "info" else f"{level}: {text}")
