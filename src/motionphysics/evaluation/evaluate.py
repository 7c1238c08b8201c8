"""Evaluate one run directory from its files: what ``motionphysics eval`` writes.

Reads only the files of a run directory (README.md, "Run directory": ``run.yaml``,
``params.json``, ``trajectory.npz``, ``video.mp4``), each optional except the trajectory, so a run made
by another tool evaluates the same way. Nothing here imports the pipeline.

``metrics.json`` keys (beside the physical diagnostics of ``metrics.physical``):

- ``ecms`` (number or null) and ``ecms_terms`` ``{motion, temporal, spatial}``, with
  ``ecms_details`` (flow backend, flow size, every ECMS choice) — ``metrics.ecms``;
- ``clipsim`` (mean cosine over all frames, CLIP ViT-L/14) or null with ``clipsim_reason``;
- ``oc`` (VBench overall consistency, ViCLIP; raw cosine, papers print x100) or null
  with ``oc_reason``;
- ``motion_adherence`` ``{score, prompt, behaviours: [...]}`` — ``metrics.adherence``;
- ``prompt`` / ``prompt_source``: the sentence scored (``--prompt`` or the run's).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["evaluate_run", "read_run_files", "floor_from_config", "summary_lines"]

SCHEMA = "motionphysics.metrics/2"


def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml

    if not path.is_file():
        return {}
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise UserInputError(f"{path}: not readable YAML ({str(err).splitlines()[0]})") from None
    return data if isinstance(data, dict) else {}


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise UserInputError(f"{path}: not valid JSON ({err})") from None
    return data if isinstance(data, dict) else {}


def read_run_files(run_dir: str | Path) -> dict[str, Any]:
    """``{"path", "config", "params", "traj", "video_path"}`` of a run directory.

    Only ``trajectory.npz`` is required; the others are {} / None when absent.
    """
    from motionphysics.io.rundir import read_trajectory

    p = Path(run_dir)
    if not p.is_dir():
        raise UserInputError(f"{p}: not a directory (expected a run directory)")
    if not (p / "trajectory.npz").is_file():
        raise UserInputError(
            f"{p}: no trajectory.npz (not a run directory, or the run did not finish)"
        )
    video = p / "video.mp4"
    return {
        "path": p,
        "config": _read_yaml(p / "run.yaml"),
        "params": _read_json(p / "params.json"),
        "traj": read_trajectory(p / "trajectory.npz"),
        "video_path": video if video.is_file() else None,
    }


def floor_from_config(config: dict[str, Any], up: np.ndarray, x0: np.ndarray) -> float | None:
    """Ground height along ``up`` [m] from run.yaml's surface colliders, or None.

    A ``surface_collider`` whose normal is within ~8 deg of ``up`` is a floor; of those
    below the object's initial lowest point (5 cm tolerance), the highest is taken.
    """
    lowest = float(np.percentile(np.asarray(x0, dtype=np.float64) @ up, 0.5))
    best = None
    for bc in config.get("boundary_conditions") or []:
        if not isinstance(bc, dict) or bc.get("type") != "surface_collider":
            continue
        try:
            n = np.asarray(bc.get("normal", (0, 0, 1)), dtype=np.float64).reshape(3)
            pt = np.asarray(bc.get("point", (0, 0, 0)), dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            continue
        if np.linalg.norm(n) == 0 or float(n @ up) / np.linalg.norm(n) < 0.99:
            continue
        h = float(pt @ up)
        if h <= lowest + 0.05 and (best is None or h > best):
            best = h
    return best


def _material(params: dict[str, Any], config: dict[str, Any]) -> dict[str, Any] | None:
    """``{"class", "sim"}`` for the elastic energy: params.json's simulation values."""
    cls = params.get("class")
    sim = params.get("sim")
    if cls and isinstance(sim, dict) and sim:
        return {"class": str(cls), "sim": {k: v for k, v in sim.items() if v is not None}}
    return None


def _video_frames(video_path: Path | None) -> np.ndarray | None:
    if video_path is None:
        return None
    from motionphysics.io.video import read_video

    return read_video(video_path)


def evaluate_run(
    run_dir: str | Path,
    *,
    prompt: str | None = None,
    clip: str | Path | None = None,
    viclip: str | Path | None = None,
    viclip_bpe: str | Path | None = None,
    raft: str | Path | None = None,
    flow: str = "dis",
    ecms_config=None,
    device: str = "cpu",
    write: bool = True,
    object_name: str | None = None,
) -> dict[str, Any]:
    """Every metric of one run; writes ``metrics.json`` there when ``write``.

    ``object_name`` (``eval --object NAME``, a run of several objects): the metrics of
    that object's particles, its motion adherence scored against its own phrase
    (``objects[i].prompt``, else the clause of the prompt that names it,
    :func:`motionphysics.optimize.objects.object_prompt`), written to
    ``metrics_NAME.json``; the video metrics (ECMS, CLIPSIM, OC) score the whole
    picture, so they are left null with that reason."""
    from motionphysics.metrics.adherence import motion_adherence
    from motionphysics.metrics.ecms import ECMSConfig, ecms_video
    from motionphysics.metrics.flow import FLOW_METHODS
    from motionphysics.metrics.physical import physical_metrics, up_axis

    if flow not in FLOW_METHODS:
        raise UserInputError(f"--flow: expected one of {', '.join(FLOW_METHODS)}, got {flow!r}")
    if flow == "raft" and raft is None:
        raise UserInputError("--flow raft: pass --raft PATH (a local RAFT-large state dict)")
    for flag, value, want_dir in (("--clip", clip, True), ("--viclip", viclip, False)):
        if value is None:
            continue
        pv = Path(value)
        if want_dir and not pv.is_dir():
            raise UserInputError(
                f"{flag} {pv}: not a directory (expected a local CLIP model folder)"
            )
        if not want_dir and not pv.is_file():
            raise UserInputError(
                f"{flag} {pv}: file not found (expected ViClip-InternVid-10M-FLT.pth)"
            )
    run = read_run_files(run_dir)
    cfg, params, traj = run["config"], run["params"], run["traj"]
    if prompt is not None:
        prompt_text, prompt_source = str(prompt), "--prompt"
        if not prompt_text.strip():
            raise UserInputError("--prompt: expected a sentence, got an empty string")
    elif isinstance(cfg.get("prompt"), str):
        prompt_text, prompt_source = cfg["prompt"], "run.yaml"
    elif isinstance(params.get("prompt"), str):
        prompt_text, prompt_source = params["prompt"], "params.json"
    else:
        prompt_text, prompt_source = None, None

    if object_name is not None:
        traj, params, prompt_text, prompt_source = _one_object(
            run, object_name, prompt_text, prompt_source, prompt is not None
        )
    up = up_axis(traj.get("gravity"))
    floor = floor_from_config(cfg, up, traj["x"][0])
    out: dict[str, Any] = {"schema": SCHEMA}
    out.update(physical_metrics(traj, _material(params, cfg), floor=floor))
    out["prompt"] = prompt_text
    out["prompt_source"] = prompt_source

    if object_name is not None:
        out["object"] = object_name
    frames = _video_frames(run["video_path"]) if object_name is None else None
    # ---- ECMS
    ecfg = ecms_config or ECMSConfig()
    if frames is None:
        out.update(ecms=None, ecms_terms=None, ecms_reason="no video.mp4 in the run directory")
    elif frames.shape[0] < 2:
        out.update(ecms=None, ecms_terms=None, ecms_reason="video.mp4 has a single frame")
    else:
        e = ecms_video(frames, ecfg, flow=flow, raft_weights=raft, device=device)
        out["ecms"] = e["ecms"]
        out["ecms_terms"] = e["terms"]
        out["ecms_details"] = {k: v for k, v in e.items() if k not in ("ecms", "terms")}
    # ---- CLIPSIM
    if clip is None:
        out.update(clipsim=None, clipsim_reason="no CLIP weights: pass --clip DIR")
    elif frames is None:
        out.update(clipsim=None, clipsim_reason="no video.mp4 in the run directory")
    elif prompt_text is None:
        out.update(clipsim=None, clipsim_reason="no prompt: pass --prompt TEXT")
    else:
        from motionphysics.metrics.clip import clipsim

        c = clipsim(frames, prompt_text, clip, device=device)
        out["clipsim"] = c["clipsim"]
        out["clipsim_details"] = {k: v for k, v in c.items() if k not in ("clipsim", "per_frame")}
        out["clipsim_per_frame"] = c["per_frame"]
    # ---- OC
    if viclip is None:
        out.update(
            oc=None,
            oc_reason="no ViCLIP weights: pass --viclip PATH (ViClip-InternVid-10M-FLT.pth)",
        )
    elif frames is None:
        out.update(oc=None, oc_reason="no video.mp4 in the run directory")
    elif prompt_text is None:
        out.update(oc=None, oc_reason="no prompt: pass --prompt TEXT")
    else:
        from motionphysics.metrics.viclip import overall_consistency

        o = overall_consistency(frames, prompt_text, viclip, bpe_path=viclip_bpe, device=device)
        out["oc"] = o["oc"]
        out["oc_details"] = {k: v for k, v in o.items() if k != "oc"}
    if object_name is not None:
        why = f"--object {object_name}: the video shows every object; eval without --object"
        out.update(ecms_reason=why, clipsim_reason=why, oc_reason=why)
    # ---- motion adherence
    if prompt_text is None:
        out["motion_adherence"] = {
            "score": None,
            "prompt": None,
            "behaviours": [],
            "reason": "no prompt in run.yaml or params.json: pass --prompt TEXT",
        }
    else:
        out["motion_adherence"] = motion_adherence(prompt_text, traj, floor=floor)
    # ---- what compare needs beside the metrics
    timings = params.get("timings") if isinstance(params.get("timings"), dict) else {}
    opt_time = timings.get("optimise")
    out["optimisation_time_s"] = float(opt_time) if isinstance(opt_time, (int, float)) else None
    if write:
        from motionphysics.io.rundir import to_json_text

        name = "metrics.json" if object_name is None else f"metrics_{object_name}.json"
        target = run["path"] / name
        tmp = target.with_name(f".metrics.json.tmp-{id(out)}")
        tmp.write_text(to_json_text(out))
        tmp.replace(target)
    return out


def _one_object(run, name: str, prompt_text, prompt_source, given: bool):
    """(trajectory, params, prompt, prompt source) of object ``name`` of a run of
    several objects (``eval --object``); a one-line error when it has no such object."""
    from motionphysics.metrics.physical import object_slices

    traj, params, cfg = run["traj"], run["params"], run["config"]
    if "object_id" not in traj:
        raise UserInputError(f"--object {name}: {run['path']} holds one object")
    slices = dict(object_slices(traj))
    if name not in slices:
        raise UserInputError(
            f"--object {name}: not an object of {run['path']}; expected one of {', '.join(slices)}"
        )
    objs = [o for o in params.get("objects") or [] if o.get("name") == name]
    one = {**params, "class": objs[0].get("class") if objs else None}
    one["sim"] = objs[0].get("sim") if objs else None
    if not given and prompt_text is not None:
        from motionphysics.optimize.objects import object_prompt

        entries = [o for o in cfg.get("objects") or [] if isinstance(o, dict)]
        own = [o.get("prompt") for o in entries if o.get("name") == name and o.get("prompt")]
        names = tuple(str(o.get("name")) for o in entries)
        phrase = own[0] if own else object_prompt(prompt_text, name, names)
        if phrase is not None:
            prompt_source = f"objects[{name}].prompt" if own else f"{prompt_source} (its clause)"
            prompt_text = phrase
    return slices[name], one, prompt_text, prompt_source


def _f(v: Any, spec: str = ".4g") -> str:
    return "null" if v is None else format(v, spec)


def summary_lines(m: dict[str, Any]) -> list[str]:
    """The short table ``motionphysics eval`` prints."""
    lines = []
    t = m.get("ecms_terms") or {}
    ecms = _f(m.get("ecms"))
    if m.get("ecms") is not None:
        ecms += (
            f"   (motion {_f(t.get('motion'))}, temporal {_f(t.get('temporal'))}, "
            f"spatial {_f(t.get('spatial'))}; flow {m.get('ecms_details', {}).get('flow')})"
        )
    else:
        ecms += f"   ({m.get('ecms_reason')})"
    lines.append(f"ECMS       {ecms}")
    for key, label in (("clipsim", "CLIPSIM"), ("oc", "OC")):
        v = m.get(key)
        lines.append(
            f"{label:<10} {_f(v)}" + ("" if v is not None else f"   ({m.get(key + '_reason')})")
        )
    ma = m.get("motion_adherence") or {}
    lines.append(f"adherence  {_f(ma.get('score'), '.3f')}   prompt: {ma.get('prompt')!r}")
    if ma.get("score_mean") is not None:
        # the score changed meaning with issue 27; say so where it is read
        lines.append(
            "  (what a viewer sees: peak squash, pace after contact, swing trains; the claims "
            f"combine by a harmonic mean, their plain mean is {ma['score_mean']:.3f})"
        )
    for b in ma.get("behaviours", []):
        if b.get("source", "prompt") != "prompt":
            continue
        if b.get("explain"):
            lines.append(f"  {b['name']:<14} {b['explain']}")
            continue
        lines.append(
            f"  {b['name']:<14} expected {b['expected']:<4} measured {b['measured']:.3g} "
            f"(threshold {b['threshold']:.3g}) score {b['score']:.2f}"
        )
    lines.append(
        f"physical   extent final/initial {m['final_extent_ratio']:.3f}; centroid above floor "
        f"{m['initial_centroid_height_above_floor']:.3g} -> {m['final_centroid_height_above_floor']:.3g} m; "
        f"rebound {m['rebound_ratio']:.3f}; spread {m['spread_ratio']:.3f}"
    )
    return lines
