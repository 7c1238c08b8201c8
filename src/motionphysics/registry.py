"""One registry pattern for every kind of plug-in (init backend, loss, video prior,
render backend).

A :class:`Registry` maps a name to a lazy ``"module:attr"`` entry (or the object
itself), so a heavy plug-in (a diffusers prior) is imported only when it is asked for.
``names()`` drives CLI choices and config validation; ``get()`` resolves an entry and,
for an unknown name, raises :class:`~motionphysics.errors.UserInputError` listing the
valid names. Adding a plug-in is one new module plus one ``register`` line (or one
entry in the table its package passes in).

A plug-in class may declare its own typed options as a nested pydantic model named
``Options`` (strict: ``extra="forbid"``, a docstring per field); :meth:`Registry.options`
validates a mapping against it. This module must not import any plug-in at import time.

A plug-in that was removed stays known by name (``removed``: name -> what happened to it
and why), so asking for it is refused with that reason instead of "unknown"; it is in no
list of choices.
"""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Iterable, Mapping
from typing import Any, Generic, TypeVar

from motionphysics.errors import UserInputError

__all__ = ["Choices", "Registry"]

T = TypeVar("T")


class Choices(tuple):
    """Values for an argparse ``choices``: iterating gives the valid names (the usage, the
    help and argparse's "invalid choice" message list only those); membership also admits
    the ``removed`` names, so the command receives them and refuses them in one line with
    the reason, instead of argparse's usage and "invalid choice"."""

    removed: frozenset[str]

    def __new__(cls, names: Iterable[str], removed: Iterable[str] = ()):
        self = super().__new__(cls, tuple(names))
        self.removed = frozenset(removed)
        return self

    def __contains__(self, value: object) -> bool:
        return value in self.removed or tuple.__contains__(self, value)


class Registry(Generic[T]):
    """Named plug-ins of one kind, resolved lazily.

    Parameters
    ----------
    kind:
        What the entries are, for messages ("loss", "video prior", ...).
    field:
        The config field or flag that names an entry ("optimize.loss"), for messages.
    entries:
        Initial ``name -> "module:attr" | object`` table.
    removed:
        ``name -> reason`` of plug-ins that no longer exist: the reason says what was
        removed and why ("the embedded pixel prior was removed (...)"); :meth:`check`
        refuses the name with it.
    """

    def __init__(
        self,
        kind: str,
        field: str,
        entries: Mapping[str, str | T] | None = None,
        removed: Mapping[str, str] | None = None,
    ):
        self.kind = kind
        self.field = field
        self._entries: dict[str, str | T] = dict(entries or {})
        self.removed: dict[str, str] = dict(removed or {})
        """Removed plug-ins: name -> what was removed and why (not in :meth:`names`)."""

    def register(self, name: str, entry: str | T) -> None:
        """Add (or replace) ``name``; ``entry`` is ``"module:attr"`` or the object."""
        if not name or not name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"{self.kind} name must be a simple identifier, got {name!r}")
        self._entries[name] = entry

    def names(self) -> list[str]:
        """Registered names, sorted (the CLI's choices and the config's valid values)."""
        return sorted(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def choices(self, *first: str) -> Choices:
        """argparse ``choices`` of this registry: ``first`` (e.g. ``none``), then the names;
        removed names are admitted (not listed) so that the command can refuse them with
        their reason."""
        return Choices([*first, *self.names()], self.removed)

    def __iter__(self) -> Iterable[str]:
        return iter(self.names())

    def check(self, name: str) -> str:
        """Return ``name`` if registered, else raise a one-line user error naming the choices
        (for a removed plug-in: why it was removed, then the choices)."""
        if name in self.removed and name not in self._entries:
            raise UserInputError(
                f"{self.field}: {name!r}: {self.removed[name]}; "
                f"expected one of {', '.join(self.names())}"
            )
        if name not in self._entries:
            close = difflib.get_close_matches(str(name), self.names(), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise UserInputError(
                f"{self.field}: unknown {self.kind} {name!r}{hint}; "
                f"expected one of {', '.join(self.names())}"
            )
        return name

    def module_of(self, name: str) -> str | None:
        """The module a lazy entry lives in (None for an object registered directly)."""
        entry = self._entries[self.check(name)]
        return entry.partition(":")[0] if isinstance(entry, str) else None

    def available(self, name: str) -> bool:
        """True when ``name``'s module can be found, without importing it."""
        import importlib.util

        module = self.module_of(name)
        if module is None:
            return True
        try:
            return importlib.util.find_spec(module) is not None
        except ImportError:  # a parent package is missing
            return False

    def get(self, name: str) -> T:
        """The plug-in registered as ``name``, importing it on first use."""
        entry = self._entries[self.check(name)]
        if isinstance(entry, str):
            module, _, attr = entry.partition(":")
            obj: Any = importlib.import_module(module)
            for part in attr.split("."):
                obj = getattr(obj, part)
            self._entries[name] = obj
            return obj
        return entry

    def options(self, name: str, values: Mapping[str, Any] | None) -> Any:
        """Validate ``values`` against the plug-in's ``Options`` model (None if it has none).

        Validation errors become one-line user errors naming the field path.
        """
        cls = self.get(name)
        model = getattr(cls, "Options", None)
        if model is None:
            if values:
                raise UserInputError(
                    f"{self.field}: {self.kind} {name!r} takes no options, got {sorted(values)}"
                )
            return None
        from pydantic import ValidationError

        try:
            return model.model_validate(dict(values or {}))
        except ValidationError as err:
            first = err.errors()[0]
            loc = ".".join(str(p) for p in first["loc"])
            given = first.get("input")
            raise UserInputError(
                f"{self.field}.{loc}: {first['msg']} (got {given!r}) for {self.kind} {name!r}"
            ) from None
