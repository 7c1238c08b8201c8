"""Run configs from files and flags: YAML loading, dotted overrides, path resolution,
``--params FILE`` reading and the package versions recorded in ``run.yaml``.

Every command that takes a CONFIG goes through :func:`load_run_config`; errors name the
file (or the flag) and the field, on one line. This module validates (through
:mod:`motionphysics.config`) but builds nothing: scenes, materials and simulations are
the assembly's (:mod:`motionphysics.assembly`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from motionphysics.config import MATERIAL_CLASSES, RunConfig, config_from_dict
from motionphysics.errors import UserInputError
from motionphysics.versions import versions

__all__ = ["check_plugins", "load_run_config", "read_params_file", "resolve_paths", "versions"]


def _set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    keys = dotted.split(".")
    for k in keys[:-1]:
        sub = node.get(k)
        if sub is None:
            sub = {}
            node[k] = sub
        if not isinstance(sub, dict):
            raise UserInputError(f"{k}: expected a mapping to set {dotted}")
        node = sub
    node[keys[-1]] = value


def resolve_paths(data: dict[str, Any], base: Path | None) -> dict[str, Any]:
    """Make file paths in a config mapping absolute.

    A relative ``scene.source`` / ``camera.cameras_json`` is looked up beside the
    config file first, then in the working directory (so a config and its assets can
    be moved together, and ``run.yaml`` works from anywhere).
    """

    def fix(value: Any) -> Any:
        if not isinstance(value, str) or value.startswith("builtin:") or not value.strip():
            return value
        p = Path(value).expanduser()
        if p.is_absolute():
            return str(p)
        if base is not None and (base / p).exists():
            return str((base / p).resolve())
        if p.exists():
            return str(p.resolve())
        return value  # left as given: the loader reports it missing, naming it as written

    for section, key in (("scene", "source"), ("camera", "cameras_json")):
        sec = data.get(section)
        if isinstance(sec, dict) and key in sec:
            sec[key] = fix(sec[key])
    objects = data.get("objects")
    if isinstance(objects, list):  # each object's own scene.source
        for obj in objects:
            if isinstance(obj, dict) and "source" in obj:
                obj["source"] = fix(obj["source"])
    return data


def load_run_config(
    path: str | Path | None, overrides: Mapping[str, Any] | None = None
) -> RunConfig:
    """Read a YAML run config (or the defaults when ``path`` is None), apply overrides.

    ``overrides`` maps dotted config paths (``"prompt"``, ``"optimize.iterations"``,
    ``"device"``...) to values from the command line; they win over the file. Errors
    name the file (or the flag) and the field, on one line.
    """
    import yaml

    origin = "<defaults>"
    data: dict[str, Any] = {}
    base = None
    if path is not None:
        p = Path(path)
        origin = str(p)
        if not p.is_file():
            raise UserInputError(f"{p}: config file not found")
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except yaml.YAMLError as err:
            raise UserInputError(f"{p}: not valid YAML ({str(err).splitlines()[0]})") from None
        except UnicodeDecodeError:
            raise UserInputError(f"{p}: not a text file (expected a YAML run config)") from None
        if not isinstance(data, dict):
            raise UserInputError(f"{p}: expected a YAML mapping at the top level")
        base = p.resolve().parent
    data = dict(data)
    data.pop("versions", None)  # informational in run.yaml; never an input
    for key, value in (overrides or {}).items():
        if value is not None:
            _set_path(data, key, value)
    cfg = config_from_dict(resolve_paths(data, base), origin)
    check_plugins(cfg, origin)
    return cfg


def check_plugins(cfg: RunConfig, origin: str = "<config>") -> None:
    """Plug-in names and options of ``cfg`` against the registries (one-line user errors).

    ``optimize.prior`` (``none`` or a ``PRIORS`` name; a removed one is refused with the
    reason, :func:`motionphysics.priors.removed_prior`), ``optimize.loss`` and every
    ``optimize.losses[i]`` (a ``LOSSES`` name; its options validated by the loss's
    ``Options`` model through ``LOSSES.options``).
    """
    from motionphysics.losses import LOSSES
    from motionphysics.priors import PRIORS, removed_prior

    opt = cfg.optimize
    try:
        removed = removed_prior(opt.prior, "optimize.prior")
        if removed is not None:
            raise UserInputError(removed)
        if opt.prior != "none" and opt.prior not in PRIORS:
            import difflib

            names = ["none", *PRIORS.names()]
            close = difflib.get_close_matches(str(opt.prior), names, n=1)
            hint = f"; did you mean `{close[0]}`?" if close else ""
            raise UserInputError(
                f"optimize.prior: got {opt.prior!r}; expected one of {', '.join(names)}{hint}"
            )
        if opt.losses is None:
            if opt.loss is not None:
                LOSSES.check(opt.loss)
            return
        for i, spec in enumerate(opt.losses):
            where = f"optimize.losses[{i}]"
            if spec.type not in LOSSES:
                raise UserInputError(
                    f"{where}.type: unknown loss {spec.type!r}; expected one of "
                    f"{', '.join(LOSSES.names())}"
                )
            try:
                LOSSES.options(spec.type, spec.options())
            except UserInputError as err:
                # the registry names its own field (optimize.loss); name the entry instead
                text = str(err)
                if text.startswith(LOSSES.field):
                    text = where + text[len(LOSSES.field) :]
                raise UserInputError(text) from None
    except UserInputError as err:
        raise UserInputError(f"{origin}: {err}") from None


def read_params_file(path: str | Path) -> dict[str, Any]:
    """Read ``--params FILE``: a run's ``params.json`` or a plain ``{class, density, params}``.

    Returns ``{"class": str, "density": float, "params": {name: float}}`` (not yet
    validated against the catalogue; that happens with the config overrides).
    """
    import json

    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"{p}: params file not found")
    try:
        data = json.loads(p.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise UserInputError(f"{p}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise UserInputError(f"{p}: expected a JSON object with class, density, params")
    cls = data.get("class")
    if not isinstance(cls, str):
        raise UserInputError(
            f"{p}: field 'class' missing (expected one of {', '.join(MATERIAL_CLASSES)})"
        )
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise UserInputError(f"{p}: field 'params' must be an object of parameter values (SI)")
    if "density" not in data:
        raise UserInputError(f"{p}: field 'density' missing (expected kg/m^3)")
    return {"class": cls, "density": data["density"], "params": dict(params), "origin": str(p)}
