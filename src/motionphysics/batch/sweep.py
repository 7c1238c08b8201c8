"""Sweep files: one base run config, axes of dotted config keys, zipped groups -> jobs.

A sweep file (YAML)::

    name: birds                      # optional; default: the file's stem
    base: examples/demo.yaml         # a run config (relative to this file, then the
                                     # working directory), or an inline mapping
    axes:                            # dotted config key -> list of values
      prompt: ["A rubber bird bounces.", "A steel bird hits the ground."]
      scene.source: [builtin:bird, builtin:duck]
      optimize.seed: [0, 1]
    zip: [[prompt, scene.source]]    # optional: axes that advance together
    out: runs/birds                  # optional; relative to this file

The jobs are the product of the axes, where every ``zip`` group counts as one axis
whose values are taken in step. Each job's config is the base with its axis values
applied as overrides, validated by the public loader
(:func:`motionphysics.runconfig.load_run_config`), so a sweep accepts exactly what
``motionphysics run`` accepts. Every job of a sweep is validated before anything runs;
the first problem is one :class:`~motionphysics.errors.UserInputError` line naming the
sweep file, the axis and the value.

A job's id is a readable slug of its axis values plus a short hash of them (sorted by
key, so reordering axes in the file keeps the ids); the same values always give the
same id. The resolved config's hash tells the runner whether a job directory holds
this job's results or those of an earlier, different sweep.

This module reads files and validates; it never writes or runs anything.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from motionphysics.errors import UserInputError

__all__ = ["Job", "Sweep", "SWEEP_KEYS", "config_hash", "job_id", "load_sweep"]

SWEEP_KEYS = ("name", "base", "axes", "zip", "out")
"""Top-level keys of a sweep file; anything else is an error."""

_KEY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass(frozen=True)
class Job:
    """One run of a sweep."""

    id: str
    """Directory name under ``OUT/jobs/``: slug of the axis values + 8 hex digits."""
    index: int
    """Position in the sweep's job order (product order, first axis slowest)."""
    values: dict[str, Any]
    """Axis key -> value as written in the sweep file, in the file's axis order."""
    config: Any = field(repr=False)
    """The validated :class:`~motionphysics.config.RunConfig`."""
    config_text: str = field(repr=False)
    """``dump_config(config)``: the fully resolved config the job runs (``job.yaml``)."""
    config_hash: str = ""
    """SHA-256 (16 hex digits) of the resolved config without ``versions``."""

    @property
    def optimised(self) -> bool:
        """True when the job optimises (a prior and at least one iteration)."""
        opt = self.config.optimize
        return opt.prior != "none" and opt.iterations > 0

    @property
    def needs_gpu(self) -> bool:
        return self.config.device == "cuda"


@dataclass(frozen=True)
class Sweep:
    """A parsed and fully validated sweep file."""

    path: Path
    name: str
    base: str
    """The base as described in messages (a path, or ``<inline>``)."""
    axes: dict[str, list[Any]]
    zip: list[tuple[str, ...]]
    out: Path
    jobs: list[Job]

    def job_dir(self, job: Job) -> Path:
        return self.out / "jobs" / job.id


# --------------------------------------------------------------------------------------
# ids and hashes
# --------------------------------------------------------------------------------------
def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def _slug_value(value: Any, limit: int = 24) -> str:
    if isinstance(value, str):
        # A path names the file, not the folders it sits in.
        text = value.rstrip("/").rsplit("/", 1)[-1] if "/" in value else value
    elif isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, (int, float)) or value is None:
        text = json.dumps(value)
    else:
        text = _canonical(value)
    text = re.sub(r"[^a-z0-9.+]+", "-", text.lower()).strip("-.")
    return text[:limit].strip("-.")


def job_id(values: Mapping[str, Any]) -> str:
    """Stable, readable id of a job from its axis values.

    ``slug-of-values-<8 hex>``: the slug joins the values (sorted by axis key, each cut
    to 24 characters, all to 64); the hash covers the exact values, so two jobs whose
    slugs coincide still get different ids.
    """
    digest = hashlib.sha256(_canonical(dict(values)).encode()).hexdigest()[:8]
    parts = [p for p in (_slug_value(values[k]) for k in sorted(values)) if p]
    slug = "_".join(parts)[:64].strip("_-.")
    return f"{slug}-{digest}" if slug else f"job-{digest}"


def config_hash(cfg) -> str:
    """Hash of a resolved :class:`RunConfig` (``versions`` excluded: informational)."""
    from motionphysics.config import config_to_dict

    data = config_to_dict(cfg)
    data.pop("versions", None)
    return hashlib.sha256(_canonical(data).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------
def _show(value: Any) -> str:
    return json.dumps(value, ensure_ascii=False, default=str)


def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml

    if not path.is_file():
        raise UserInputError(f"{path}: sweep file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise UserInputError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    except UnicodeDecodeError:
        raise UserInputError(f"{path}: not a text file (expected a YAML sweep file)") from None
    if not isinstance(data, dict):
        raise UserInputError(f"{path}: expected a YAML mapping with base, axes, zip, out")
    return data


def _find_file(value: str, here: Path) -> Path | None:
    """A relative path beside the sweep file first, then in the working directory."""
    p = Path(value).expanduser()
    if p.is_absolute():
        return p if p.is_file() else None
    for cand in (here / p, p):
        if cand.is_file():
            return cand.resolve()
    return None


def _parse_axes(path: Path, raw: Any) -> dict[str, list[Any]]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise UserInputError(f"{path}: axes: expected a mapping of dotted config keys to lists")
    axes: dict[str, list[Any]] = {}
    for key, values in raw.items():
        if not isinstance(key, str) or not _KEY_RE.match(key):
            raise UserInputError(
                f"{path}: axes: {_show(key)} is not a dotted config key (e.g. optimize.seed)"
            )
        if not isinstance(values, list) or not values:
            raise UserInputError(f"{path}: axes.{key}: expected a non-empty list of values")
        seen: set[str] = set()
        for v in values:
            if v is None:
                # load_run_config skips None overrides, so null would silently mean
                # "the base's value": refuse it rather than run the wrong job.
                raise UserInputError(
                    f"{path}: axes.{key}: value null is not supported (it would keep the "
                    "base's value); give explicit values"
                )
            c = _canonical(v)
            if c in seen:
                raise UserInputError(f"{path}: axes.{key}: value {_show(v)} appears twice")
            seen.add(c)
        axes[key] = list(values)
    for a in axes:
        for b in axes:
            if a != b and b.startswith(a + "."):
                raise UserInputError(
                    f"{path}: axes: {a} and {b} overlap (one is inside the other); keep one"
                )
    return axes


def _parse_zip(path: Path, raw: Any, axes: dict[str, list[Any]]) -> list[tuple[str, ...]]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise UserInputError(f"{path}: zip: expected a list of groups of axis keys")
    groups: list[tuple[str, ...]] = []
    used: dict[str, int] = {}
    for i, group in enumerate(raw):
        if not isinstance(group, list) or len(group) < 2:
            raise UserInputError(
                f"{path}: zip[{i}]: expected a list of at least two axis keys, got {_show(group)}"
            )
        for key in group:
            if key not in axes:
                raise UserInputError(
                    f"{path}: zip[{i}]: {_show(key)} is not an axis (axes: {', '.join(axes) or 'none'})"
                )
            if key in used:
                raise UserInputError(f"{path}: zip[{i}]: axis {key} is already in zip[{used[key]}]")
            used[key] = i
        lengths = {k: len(axes[k]) for k in group}
        if len(set(lengths.values())) != 1:
            shown = ", ".join(f"{k} has {n}" for k, n in lengths.items())
            raise UserInputError(
                f"{path}: zip[{i}]: zipped axes need the same number of values ({shown})"
            )
        groups.append(tuple(group))
    return groups


def _expand(axes: dict[str, list[Any]], groups: list[tuple[str, ...]]) -> list[dict[str, Any]]:
    """The jobs' axis values: product over groups (a zip group or a lone axis), file order."""
    in_zip = {k: g for g in groups for k in g}
    units: list[tuple[str, ...]] = []
    for key in axes:
        unit = in_zip.get(key, (key,))
        if unit not in units:
            units.append(unit)
    choices = [
        [dict(zip(u, vals, strict=True)) for vals in zip(*(axes[k] for k in u), strict=True)]
        for u in units
    ]
    out = []
    for combo in itertools.product(*choices):
        merged: dict[str, Any] = {}
        for part in combo:
            merged.update(part)
        out.append({k: merged[k] for k in axes})  # file order
    return out


# --------------------------------------------------------------------------------------
# validation through the public loader
# --------------------------------------------------------------------------------------
def _resolve_axis_paths(key: str, value: Any, here: Path) -> Any:
    """File values of an axis (``scene.source`` ...) are relative to the sweep file first.

    Uses the pipeline's own ``resolve_paths`` on the override as a nested mapping, so an
    axis over ``scene`` (a whole mapping) or ``scene.source`` is treated alike.
    """
    from motionphysics.runconfig import resolve_paths

    nested: dict[str, Any] = {}
    node = nested
    parts = key.split(".")
    for k in parts[:-1]:
        node = node.setdefault(k, {})
    node[parts[-1]] = copy.deepcopy(value)
    resolve_paths(nested, here)
    node = nested
    for k in parts:
        node = node[k]
    return node


class _Loader:
    """Validates job configs with ``load_run_config(base_file, overrides)``."""

    def __init__(self, sweep_path: Path, base_file: Path, origin: str, described: str):
        self.sweep_path = sweep_path
        self.base_file = base_file
        self.origin = origin  # the prefix load_run_config puts on its messages
        self.described = described

    def load(self, overrides: Mapping[str, Any]):
        from motionphysics.runconfig import load_run_config

        return load_run_config(self.base_file, dict(overrides))

    def strip(self, err: UserInputError) -> str:
        msg = str(err)
        prefix = f"{self.origin}: "
        return msg[len(prefix) :] if msg.startswith(prefix) else msg

    def blame(self, values: Mapping[str, Any], overrides: Mapping[str, Any], err) -> UserInputError:
        """One line naming the axis (and value) that makes this job's config invalid."""
        msg = self.strip(err)
        try:
            self.load({})
        except UserInputError as base_err:
            if self.strip(base_err) == msg:
                return UserInputError(f"{self.sweep_path}: base {self.described}: {msg}")
        else:
            for key in values:
                try:
                    self.load({key: overrides[key]})
                except UserInputError as one:
                    return UserInputError(
                        f"{self.sweep_path}: axes.{key}: value {_show(values[key])}: {self.strip(one)}"
                    )
        shown = ", ".join(f"{k}={_show(v)}" for k, v in values.items())
        return UserInputError(f"{self.sweep_path}: job {shown}: {msg}")


def load_sweep(path: str | Path, out: str | Path | None = None) -> Sweep:
    """Read, expand and validate a sweep file (every job's config, through the loader).

    ``out`` (the ``--out`` flag) wins over the file's ``out:``, which is relative to the
    sweep file; without either the sweep goes to ``runs/<name>`` in the working directory
    (as ``motionphysics run`` does with ``runs/<config stem>``).
    """
    from motionphysics.config import dump_config

    path = Path(path)
    data = _read_yaml(path)
    unknown = [k for k in data if k not in SWEEP_KEYS]
    if unknown:
        raise UserInputError(
            f"{path}: {unknown[0]}: unknown key (a sweep file has {', '.join(SWEEP_KEYS)})"
        )
    here = path.resolve().parent

    # Without a name: the file's stem, made folder-safe ("my sweep.yaml" -> my-sweep).
    name = data.get("name", re.sub(r"[^A-Za-z0-9._-]+", "-", path.stem).strip("-.") or "sweep")
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise UserInputError(
            f"{path}: name: expected a simple name (letters, digits, . _ -), got {_show(name)}"
        )

    axes = _parse_axes(path, data.get("axes"))
    groups = _parse_zip(path, data.get("zip"), axes)

    if out is not None:
        out_dir = Path(out)
    elif data.get("out") is not None:
        if not isinstance(data["out"], str) or not data["out"].strip():
            raise UserInputError(f"{path}: out: expected a directory path")
        p = Path(data["out"]).expanduser()
        out_dir = p if p.is_absolute() else here / p
    else:
        out_dir = Path("runs") / name

    base = data.get("base")
    with tempfile.TemporaryDirectory(prefix="motionphysics-sweep-") as tmp:
        if base is None or isinstance(base, dict):
            import yaml

            from motionphysics.runconfig import resolve_paths

            # An inline base is a config written in the sweep file: its file paths are
            # relative to the sweep file. The loader reads files, so hand it one.
            inline = resolve_paths(copy.deepcopy(base or {}), here)
            base_file = Path(tmp) / "base.yaml"
            try:
                base_file.write_text(yaml.safe_dump(inline, sort_keys=False))
            except yaml.YAMLError as err:
                raise UserInputError(f"{path}: base: cannot be written as YAML ({err})") from None
            described = "(inline)"
        elif isinstance(base, str) and base.strip():
            found = _find_file(base, here)
            if found is None:
                raise UserInputError(
                    f"{path}: base: run config {base!r} not found (relative to the sweep file "
                    "or the working directory)"
                )
            base_file = found
            described = base
        else:
            raise UserInputError(
                f"{path}: base: expected a run config path or an inline mapping, got {_show(base)}"
            )
        loader = _Loader(path, base_file, str(base_file), described)

        jobs: list[Job] = []
        ids: dict[str, int] = {}
        for index, values in enumerate(_expand(axes, groups)):
            overrides = {k: _resolve_axis_paths(k, v, here) for k, v in values.items()}
            try:
                cfg = loader.load(overrides)
            except UserInputError as err:
                raise loader.blame(values, overrides, err) from None
            jid = job_id(values)
            if jid in ids:  # only on a hash collision of different values
                raise UserInputError(f"{path}: jobs {ids[jid]} and {index} get the same id {jid}")
            ids[jid] = index
            jobs.append(
                Job(
                    id=jid,
                    index=index,
                    values=values,
                    config=cfg,
                    config_text=dump_config(cfg),
                    config_hash=config_hash(cfg),
                )
            )
    return Sweep(
        path=path,
        name=name,
        base=described,
        axes=axes,
        zip=groups,
        out=out_dir,
        jobs=jobs,
    )
