"""What ``--resume`` does with a run directory: refuse, report "already complete", or
say from where the run continues.

:func:`plan_resume` reads what a run left (``run.yaml``, ``params.json``,
``checkpoint.pt``) and compares the requested config with ``run.yaml``:

- no run in the folder: a new run starts (and says so);
- a different config (or command, or ``fit`` reference / iteration count): refused,
  exit 2, naming the first differing key and both values (``--force`` starts over);
- a complete run of the same config: ``complete``; the caller writes nothing;
- an interrupted, killed or failed run of the same config: ``continue``, with one line
  saying which stage it stopped in and where it goes on (the optimisation from its
  checkpoint; ``fit``'s global search from its first candidate; any other stage
  cannot continue mid-way and is restarted).

"The same config": every value the request sets equals the recorded one; a value the
request leaves open (``null``: the material when it is estimated, an auto-framed
camera, ``optimize.loss`` filled from ``optimize.losses``) matches whatever the run
resolved it to. ``versions`` are not compared (a resumed run records the new ones).

This module reads the run directory; it writes nothing and decides nothing about how a
stage is computed (the pipeline and the optimisation loop do).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from motionphysics.errors import UserInputError

__all__ = [
    "OPTIMISE_STAGE",
    "ResumePlan",
    "completed_result",
    "config_difference",
    "open_keys",
    "plan_resume",
]

OPTIMISE_STAGE = "optimise"
"""The one stage that continues mid-way (from ``checkpoint.pt``)."""
_BEFORE_OPTIMISE = {
    "start",
    "load scene",
    "reference render",
    "estimate material",
    "resolve material",
}
"""Stages a run passes before the optimisation (redone from the config on resume)."""
GLOBAL_STAGE = "global search"
"""``fit``'s forward-only stage before the gradient stage: it keeps no checkpoint (its
candidates are cheap rollouts), so a resume redoes it from its first candidate."""

Action = Literal["new", "complete", "continue", "restart"]


@dataclass(frozen=True)
class ResumePlan:
    """What a ``--resume`` does; :attr:`message` is the one line the command prints."""

    action: Action
    """``new`` (no run there), ``complete`` (nothing to do), ``continue`` (an interrupted
    run of the same config), ``restart`` (a different config, ``--force`` given)."""
    run_dir: Path
    message: str
    stage: str | None = None
    """The stage the interrupted run stopped in (``params.json: stage``)."""
    iteration: int | None = None
    """Optimisation iterations already done (``checkpoint.pt``), when there is one."""
    iterations: int | None = None
    """The optimisation's total iterations, when known."""

    @property
    def resume(self) -> bool:
        """Whether the writer keeps the files (``continue``) rather than starting afresh."""
        return self.action == "continue"


def _show(v: Any) -> str:
    text = json.dumps(v) if not isinstance(v, str) else repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def config_difference(
    requested: Any, recorded: Any, path: str = "", open_keys: frozenset[str] = frozenset()
) -> tuple[str, Any, Any] | None:
    """First ``(dotted key, requested, recorded)`` where the request sets a value the
    recorded config does not hold; ``None`` when they agree (see the module docstring).

    Keys are visited in the request's order; list items as ``key[i]``. ``open_keys``:
    dotted keys the request leaves to the run although they hold a default (the
    auto-framed camera), matched like ``null``.
    """
    if requested is None or path in open_keys:
        return None  # left open by the request: the run resolved it
    if isinstance(requested, Mapping):
        if not isinstance(recorded, Mapping):
            return (path or "<config>", requested, recorded)
        for k, v in requested.items():
            sub = f"{path}.{k}" if path else str(k)
            if k not in recorded:
                if v is None:
                    continue
                return (sub, v, None)
            d = config_difference(v, recorded[k], sub, open_keys)
            if d is not None:
                return d
        return None
    if isinstance(requested, (list, tuple)):
        if not isinstance(recorded, (list, tuple)) or len(recorded) != len(requested):
            return (path, requested, recorded)
        for i, (a, b) in enumerate(zip(requested, recorded, strict=True)):
            d = config_difference(a, b, f"{path}[{i}]", open_keys)
            if d is not None:
                return d
        return None
    if isinstance(requested, bool) or isinstance(recorded, bool):
        return None if requested is recorded else (path, requested, recorded)
    if requested != recorded:
        return (path, requested, recorded)
    return None


def _plain_config(cfg) -> dict[str, Any]:
    """The request as ``run.yaml`` would hold it (JSON-normalised, no ``versions``)."""
    from motionphysics.config import config_to_dict
    from motionphysics.io.rundir import to_json_text

    data = json.loads(to_json_text(config_to_dict(cfg)))
    data.pop("versions", None)
    return data


def open_keys(cfg) -> frozenset[str]:
    """Keys of ``cfg`` that hold a default the run replaces by what it resolved:
    ``camera.radius`` / ``camera.look_at`` when neither is set and there is no
    capture camera file (``camera.from`` / ``cameras_json``; auto-framing,
    :func:`motionphysics.assembly.resolve_camera`)."""
    cam = cfg.camera
    if getattr(cam, "camera_file", None) or {"radius", "look_at"} & cam.model_fields_set:
        return frozenset()
    return frozenset({"camera.radius", "camera.look_at"})


def _read_recorded(run_dir: Path) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    import yaml

    recorded = None
    y = run_dir / "run.yaml"
    if y.is_file():
        try:
            recorded = yaml.safe_load(y.read_text())
        except (OSError, yaml.YAMLError) as err:
            raise UserInputError(
                f"{y}: unreadable ({type(err).__name__}); cannot tell whether --resume "
                "continues the same config; pass --force to start over"
            ) from None
        if not isinstance(recorded, dict):
            raise UserInputError(
                f"{y}: not a run config (expected a mapping); pass --force to start over"
            )
        recorded.pop("versions", None)
    params = None
    p = run_dir / "params.json"
    if p.is_file():
        try:
            params = json.loads(p.read_text())
        except (OSError, ValueError):
            params = None  # a run killed before its first params.json: treated as partial
        if not isinstance(params, dict):
            params = None
    return recorded, params


def _dotted(data: Mapping[str, Any] | None, key: str) -> Any:
    cur: Any = data
    for part in key.split("."):
        if not isinstance(cur, Mapping):
            return None
        cur = cur.get(part)
    return cur


def _checkpoint_progress(run_dir: Path) -> tuple[int, str | None] | None:
    """``(iterations done, stop_reason)`` of ``checkpoint.pt``, or None when absent/torn."""
    ck = run_dir / "checkpoint.pt"
    if not ck.is_file():
        return None
    import torch  # the checkpoint is a torch file; read here, not through optimize/ (layering)

    try:
        data = torch.load(ck, map_location="cpu", weights_only=False)
        return int(data["next_iteration"]), data.get("stop_reason")
    except Exception:  # noqa: BLE001 - unreadable: the loop reports it when it resumes
        return None


def plan_resume(
    out: str | Path,
    cfg,
    *,
    command: str,
    force: bool = False,
    expect: Mapping[str, tuple[str, Any]] | None = None,
    iterations: int | None = None,
) -> ResumePlan:
    """Decide what ``--resume`` does with ``out`` for the request ``cfg``.

    command: ``run`` | ``simulate`` | ``fit`` (a run of another command is refused).
    force: a different config starts over (``restart``) instead of being refused.
    expect: request values that are not in the config, ``{label: (params.json dotted
    key, requested value)}`` (``fit``: ``--reference`` digest, ``--iters``); compared
    when the run recorded the key.
    iterations: the optimisation's total iterations (for the message), when it optimises.

    Raises UserInputError (exit 2) for a different config without ``force``.
    """
    from motionphysics.io.rundir import RunDirectory

    run_dir = Path(out)
    if not RunDirectory.holds_run(run_dir):
        return ResumePlan("new", run_dir, f"{run_dir}: nothing to resume there; starting a new run")
    recorded, params = _read_recorded(run_dir)

    diff: tuple[str, Any, Any] | None = None
    recorded_command = (params or {}).get("command")
    if recorded_command is not None and recorded_command != command:
        diff = ("command", command, recorded_command)
    if diff is None and recorded is not None:
        diff = config_difference(_plain_config(cfg), recorded, open_keys=open_keys(cfg))
    if diff is None:
        for label, (key, value) in (expect or {}).items():
            have = _dotted(params, key)
            if have is not None and value is not None and have != value:
                diff = (label, value, have)
                break
    if diff is not None:
        key, want, have = diff
        what = (
            f"{run_dir} holds a run of a different config: {key} is {_show(want)} here but "
            f"{_show(have)} in {run_dir / 'run.yaml'}"
            if key not in ("command", *(expect or {}))
            else f"{run_dir} holds a different run: {key} is {_show(want)} here but "
            f"{_show(have)} in {run_dir / 'params.json'}"
        )
        if not force:
            raise UserInputError(
                f"{what}; --resume continues only the same config (pass --force to start over, "
                "or choose another --out)"
            )
        return ResumePlan("restart", run_dir, f"{what}; --force: starting over")

    partial = RunDirectory.is_partial(run_dir)
    if not partial:
        status = (params or {}).get("status") or "complete"
        return ResumePlan(
            "complete",
            run_dir,
            f"{run_dir}: already complete (status {status}, the same config as its run.yaml); "
            "nothing to do, nothing rewritten (pass --force to run it again)",
            stage="done",
        )

    stage = (params or {}).get("stage") or "start"
    status = (params or {}).get("status") or "killed"
    if status == "running":
        status = "killed"  # params.json said running: the process died without a word
    head = f"resuming {run_dir} (it stopped in '{stage}', status {status})"
    progress = _checkpoint_progress(run_dir)
    total = iterations
    if total is None:
        total = _dotted(params, "fit.iterations") or _dotted(recorded, "optimize.iterations")
    done = progress[0] if progress else None
    of = f" of {total}" if total is not None else ""
    if stage in _BEFORE_OPTIMISE:
        tail = f"'{stage}' cannot continue mid-way: restarting it and the stages after it"
    elif stage == GLOBAL_STAGE:
        tail = (
            f"'{stage}' keeps no checkpoint: restarting the global search from its first "
            f"candidate, then the gradient stage from iteration 0{of}"
        )
    elif stage == OPTIMISE_STAGE:
        # stop_reason is set by the last checkpoint of a finished optimisation
        # ('iterations', 'converged' or 'nan'), None while it runs
        if progress is not None and progress[1] is not None:
            tail = (
                f"the optimisation had finished ({done}{of} iterations, checkpoint.pt): it is "
                "not repeated; the stages after it run (from 'simulate' at frame 0)"
            )
        elif done:
            tail = (
                f"the optimisation continues after iteration {done}{of} (checkpoint.pt; the "
                "scene and material stages before it are rebuilt from the config)"
            )
        else:
            tail = (
                "no optimisation checkpoint was written yet: restarting 'optimise' at iteration 0"
            )
    else:
        opt = ""
        if done is not None:
            opt = f"the optimisation is done ({done}{of} iterations, checkpoint.pt) and is not repeated; "
        frames = _dotted(recorded, "sim.frames")
        tail = (
            f"{opt}'{stage}' cannot continue mid-way: restarting from 'simulate' at frame 0"
            + (f" of {frames}" if frames is not None else "")
            + " (frames are kept only once 'write outputs' has run)"
            if stage in ("simulate", "render", "write outputs")
            else f"{opt}'{stage}' cannot continue mid-way: restarting from 'simulate' at frame 0"
        )
    return ResumePlan(
        "continue",
        run_dir,
        f"{head}: {tail}",
        stage=stage,
        iteration=done,
        iterations=total,
    )


def completed_result(out: str | Path):
    """The :class:`~motionphysics.io.writer.RunResult` of a complete run, read back from
    its files (for the summary of a ``--resume`` that has nothing to do)."""
    from motionphysics.io.writer import RunResult

    run_dir = Path(out)
    _, params = _read_recorded(run_dir)
    params = params or {}
    metrics = None
    m = run_dir / "metrics.json"
    if m.is_file():
        try:
            metrics = json.loads(m.read_text())
        except (OSError, ValueError):
            metrics = None
    video = run_dir / "video.mp4"
    return RunResult(
        run_dir,
        params,
        metrics,
        dict(params.get("timings") or {}),
        video if video.is_file() else None,
        None,
        list(params.get("files") or []),
    )
