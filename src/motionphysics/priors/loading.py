"""Loading a diffusers-layout model directory for a prior, with one-line user errors.

A diffusers pipeline directory (what ``save_pretrained`` writes, what
``huggingface-cli download`` fetches) holds ``model_index.json`` naming each component's
library and class, and one sub-folder per component with its ``config.json`` (models),
``scheduler_config.json`` (schedulers) or tokenizer files. This module checks that
layout *before* anything heavy is loaded, so a missing directory, a missing component or
a component of the wrong class is a :class:`~motionphysics.errors.UserInputError` with one
line naming what is missing and the command that fetches the published model -- never a
traceback from deep inside diffusers.

It must not import diffusers or transformers at module import time.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from motionphysics.errors import UserInputError

__all__ = [
    "ModelDir",
    "component_config",
    "open_model_dir",
    "resolve_dtype",
]


@dataclass(frozen=True)
class ModelDir:
    """A checked diffusers-layout directory."""

    root: Path
    """The pipeline directory (holds ``model_index.json``)."""
    index: dict[str, Any]
    """The parsed ``model_index.json`` (component -> [library, class])."""
    hub_id: str
    """The published model this prior expects (for messages)."""
    prior: str
    """The prior's registry name (for messages)."""

    def hint(self) -> str:
        return f"get it with: huggingface-cli download {self.hub_id} --local-dir DIR"

    def sub(self, component: str) -> Path:
        return self.root / component

    def class_name(self, component: str) -> str:
        return str(self.index[component][1])


def _download_hint(hub_id: str) -> str:
    return f"get it with: huggingface-cli download {hub_id} --local-dir DIR"


def _snapshot(repo_id: str, prior: str, hub_id: str) -> Path:
    """Download (or find in the local cache) a hub repository; one-line error offline."""
    try:
        from huggingface_hub import snapshot_download

        return Path(snapshot_download(repo_id))
    except Exception as err:  # network, auth, unknown repo: all a user-fixable condition
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserInputError(
            f"--prior-path {repo_id!r}: not a directory and the hub download failed "
            f"({reason[:160]}); for --prior {prior} {_download_hint(hub_id)} and pass "
            f"--prior-path DIR"
        ) from None


def open_model_dir(
    path: str | Path | None,
    *,
    prior: str,
    hub_id: str,
    components: Mapping[str, Iterable[str]],
) -> ModelDir:
    """Check ``path`` is a diffusers pipeline directory holding ``components``.

    ``components`` maps a component name to the class names accepted for it (an empty
    iterable accepts any class, e.g. tokenizers, which are loaded with the Auto classes).
    ``path`` may be a hub id (``owner/name``) when it is not an existing directory; it is
    then downloaded through ``huggingface_hub`` (which needs internet or a warm cache).
    """
    if path is None or str(path) == "":
        raise UserInputError(
            f"--prior {prior} needs --prior-path DIR (a diffusers model directory); "
            f"{_download_hint(hub_id)}"
        )
    root = Path(path).expanduser()
    if not root.exists():
        text = str(path)
        looks_like_hub_id = text.count("/") == 1 and not text.startswith((".", "/", "~"))
        if not looks_like_hub_id:
            raise UserInputError(
                f"--prior-path {text}: no such directory; for --prior {prior} "
                f"{_download_hint(hub_id)}"
            )
        root = _snapshot(text, prior, hub_id)
    if not root.is_dir():
        raise UserInputError(f"--prior-path {root}: not a directory; {_download_hint(hub_id)}")
    index_file = root / "model_index.json"
    if not index_file.is_file():
        raise UserInputError(
            f"--prior-path {root}: no model_index.json (not a diffusers pipeline directory); "
            f"{_download_hint(hub_id)}"
        )
    try:
        index = json.loads(index_file.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise UserInputError(f"{index_file}: not valid JSON ({err})") from None
    md = ModelDir(root=root, index=index, hub_id=hub_id, prior=prior)
    for name, accepted in components.items():
        entry = index.get(name)
        if not (isinstance(entry, list) and len(entry) == 2 and entry[1]):
            raise UserInputError(
                f"{index_file}: component {name!r} is missing (a {prior} pipeline needs "
                f"{', '.join(components)}); {md.hint()}"
            )
        accepted = tuple(accepted)
        if accepted and entry[1] not in accepted:
            raise UserInputError(
                f"{index_file}: component {name!r} is {entry[1]}, expected "
                f"{' or '.join(accepted)} for --prior {prior}; {md.hint()}"
            )
        if not md.sub(name).is_dir():
            raise UserInputError(
                f"{md.sub(name)}: missing component directory {name!r}; {md.hint()}"
            )
    return md


def component_config(md: ModelDir, component: str, filename: str = "config.json") -> dict:
    """The parsed config of ``component`` (``config.json`` / ``scheduler_config.json``)."""
    f = md.sub(component) / filename
    if not f.is_file():
        raise UserInputError(f"{f}: missing {filename} of component {component!r}; {md.hint()}")
    try:
        return json.loads(f.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise UserInputError(f"{f}: not valid JSON ({err})") from None


def require_weights(md: ModelDir, component: str) -> None:
    """A model component must hold weights (``*.safetensors`` or ``*.bin``)."""
    sub = md.sub(component)
    if not any(sub.glob("*.safetensors")) and not any(sub.glob("*.bin")):
        raise UserInputError(
            f"{sub}: no weights (*.safetensors or *.bin) for component {component!r}; {md.hint()}"
        )


def resolve_dtype(
    device: torch.device, requested: torch.dtype | str | None, cuda_default
) -> torch.dtype:
    """float32 on CPU (half precision convolutions are slow or missing there); on CUDA the
    dtype the model was trained in (``cuda_default``) unless one is requested."""
    if isinstance(requested, str):
        table = {
            "float64": torch.float64,
            "float32": torch.float32,
            "fp32": torch.float32,
            "float16": torch.float16,
            "fp16": torch.float16,
            "bfloat16": torch.bfloat16,
            "bf16": torch.bfloat16,
        }
        if requested not in table:
            raise UserInputError(
                f"prior dtype {requested!r}: expected one of {', '.join(sorted(table))}"
            )
        requested = table[requested]
    if requested is not None:
        return requested
    if device.type == "cpu":
        return torch.float32
    return cuda_default


def load_failed(md: ModelDir, component: str, err: Exception) -> UserInputError:
    """A component whose files exist but do not load (truncated weights, wrong shapes)."""
    reason = (str(err).splitlines() or [type(err).__name__])[0][:200]
    return UserInputError(
        f"{md.sub(component)}: cannot load component {component!r} ({reason}); {md.hint()}"
    )
