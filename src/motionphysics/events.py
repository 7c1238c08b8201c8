"""Observers of a run: the one interface progress displays, the web viewer and the
sweep runner implement to follow what a command is doing.

The library calls :func:`emit`-style methods on an :class:`Observer`; every method has a
no-op default, so an observer implements only what it needs. :class:`Observers` fans one
call out to several. Observers must not raise into the run: an exception in an observer
is a bug in the observer, and is re-raised (not swallowed) so tests see it.

This module must not import anything heavy (no torch, no warp).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["Observer", "Observers", "NullObserver"]


class Observer:
    """Callbacks of one run. All methods are optional no-ops."""

    def run_started(self, command: str, out_dir: str | None) -> None:
        """A command began writing ``out_dir`` (None when it writes no run directory)."""

    def stage_started(self, name: str, total: int | None = None) -> None:
        """A stage (``scene``, ``init``, ``simulate``, ``render``, ``optimize``, ...) began;
        ``total`` is its number of steps when known (frames, iterations)."""

    def stage_advanced(self, name: str, done: int, total: int | None = None) -> None:
        """``done`` steps of stage ``name`` are complete."""

    def stage_finished(self, name: str, seconds: float) -> None:
        """Stage ``name`` finished after ``seconds`` of wall time."""

    def frame_simulated(self, frame: int, frames: int) -> None:
        """Output frame ``frame`` (0-based) of ``frames`` has been simulated."""

    def iteration_done(self, iteration: int, record: Mapping[str, Any]) -> None:
        """Optimisation iteration ``iteration`` finished; ``record`` is its ``log.jsonl`` line."""

    def message(self, level: str, text: str) -> None:
        """A line for the person: ``level`` is ``info`` or ``warning``."""

    def run_finished(self, status: str, summary: Mapping[str, Any] | None = None) -> None:
        """The command ended: ``status`` is ``complete``, ``failed`` or ``interrupted``."""


class NullObserver(Observer):
    """Observes nothing (the default where no display is wanted)."""


class Observers(Observer):
    """Fans every callback out to each observer, in order."""

    def __init__(self, observers: Iterable[Observer] = ()):
        self.observers: list[Observer] = [o for o in observers if o is not None]

    def add(self, observer: Observer) -> None:
        self.observers.append(observer)

    def __getattribute__(self, name: str):
        if name.startswith("_") or name in ("observers", "add"):
            return object.__getattribute__(self, name)
        if name in Observer.__dict__ and callable(Observer.__dict__[name]):
            observers = object.__getattribute__(self, "observers")

            def fan_out(*args, **kwargs):
                for obs in observers:
                    getattr(obs, name)(*args, **kwargs)

            return fan_out
        return object.__getattribute__(self, name)
