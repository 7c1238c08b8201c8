"""The one run-directory writer behind ``run``, ``simulate`` and ``fit``.

A :class:`RunWriter` owns a :class:`~motionphysics.io.rundir.RunDirectory` (every
file written atomically) and the ``params.json`` state of the run:

- :meth:`RunWriter.begin` writes ``run.yaml`` and ``params.json`` (``partial: true``);
- :meth:`RunWriter.stage` times a stage in the progress display, tells the observer,
  and rewrites ``params.json`` on entry and exit, so a run killed at any point leaves
  a directory that says how far it got;
- the ``record_*`` / ``write_*`` methods fill the state and write the outputs:
  ``scene.ply`` (the prepared rest splats, INRIA layout), ``plots/reference.png``,
  ``video.mp4``, ``trajectory.npz``, ``metrics.json``, ``plots/``;
- :meth:`RunWriter.finish` writes ``report.html`` and the final ``params.json``
  (``partial: false``); :meth:`RunWriter.guard` turns Ctrl-C and errors into a
  consistent partial directory (``status: interrupted`` / ``failed``).

``params.json`` has one schema (:data:`PARAMS_SCHEMA`, key set :data:`PARAMS_KEYS`)
for every command; a key that does not apply to a command is ``null`` (``reference``
and ``fit`` outside ``fit``; ``optimise`` when nothing was optimised). The summary a
command prints is :func:`summary_text` of the result, the same for every command.

This module writes files; it runs no simulation and renders nothing (the assembly
does) and must not import ``motionphysics.pipeline``, ``motionphysics.commands`` or
``motionphysics.optimize``.
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import RunInterrupted
from motionphysics.events import NullObserver, Observer

__all__ = [
    "PARAMS_KEYS",
    "PARAMS_SCHEMA",
    "UNITS",
    "RunResult",
    "RunWriter",
    "format_value",
    "print_summary",
    "summary_text",
]

PARAMS_SCHEMA = "motionphysics.params/1"
PARAMS_KEYS = (
    "schema",
    "command",
    "prompt",
    "partial",
    "status",
    "stage",
    "error",
    "seed",
    "device",
    "versions",
    "scene",
    "camera",
    "class",
    "class_id",
    "density",
    "params",
    "units",
    "sim",
    "sim_context",
    "objects",
    "provenance",
    "initial",
    "history",
    "optimise",
    "reference",
    "fit",
    "metrics",
    "plots",
    "files",
    "timings",
    "wall_time_s",
)
"""Every ``params.json`` holds exactly these keys (README, "params.json")."""


UNITS = {
    "density": "kg/m^3",
    "E": "Pa",
    "nu": "-",
    "tau_Y": "Pa",
    "eta": "-",
    "theta_fric": "deg",
    "mu": "Pa s",
    "kappa": "Pa",
    "n": "-",
}
"""SI unit of each physical parameter (``params.json``: ``units``)."""


def _class_id(cls: str) -> int:
    from motionphysics.materials.catalog import class_id

    return class_id(cls)


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):
        return a.detach().cpu().numpy()
    return np.asarray(a)


@dataclass
class RunResult:
    run_dir: Path
    params: dict[str, Any]
    metrics: dict[str, Any] | None
    timings: dict[str, float]
    video: Path | None
    config: Any
    files: list[str] = field(default_factory=list)


@contextmanager
def _no_sigint():
    """Hold Ctrl-C off while the final bookkeeping of an interrupted run is written."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@contextmanager
def _child_stderr_held():
    """Hold what is written to file descriptor 2 (ffmpeg, a child process, writes there
    directly) while the body runs: replayed when it succeeds, dropped when it fails
    (the failure is then reported in one line, not in ffmpeg's dozen)."""
    import os
    import tempfile

    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all
        yield
        return
    held = tempfile.TemporaryFile()
    ok = False
    try:
        sys.stderr.flush()
        os.dup2(held.fileno(), 2)
        yield
        ok = True
    finally:
        try:
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
        os.dup2(saved, 2)
        os.close(saved)
        if ok:
            held.seek(0)
            data = held.read()
            if data:
                os.write(2, data)
        held.close()


def _check_mp4(path: Path) -> None:
    """Raise OSError unless ``path`` is a whole MP4: top-level boxes that tile the file
    exactly, with ``ftyp``, ``moov`` and ``mdat`` among them."""
    import errno
    import os
    import struct

    size = path.stat().st_size
    seen: set[bytes] = set()
    pos = 0
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(8)
            if len(head) < 8:
                break
            n, kind = struct.unpack(">I4s", head)
            if n == 1:
                big = f.read(8)
                if len(big) < 8:
                    break
                n = struct.unpack(">Q", big)[0]
            elif n == 0:
                n = size - pos
            if n < 8 or pos + n > size:
                break
            seen.add(kind)
            pos += n
    if pos != size or not {b"ftyp", b"moov", b"mdat"} <= seen:
        full = False
        try:
            full = os.statvfs(path.parent).f_bavail == 0
        except OSError:
            pass
        code = errno.ENOSPC if full else errno.EIO
        raise OSError(code, f"the video encoder left an incomplete file ({size} bytes)")


def _fps(frame_dt: float) -> float:
    return max(1.0, min(60.0, 1.0 / frame_dt))


def versions() -> dict[str, str]:
    from motionphysics.versions import versions as _versions

    return _versions()


class RunWriter:
    """Writes one run directory (see the module docstring).

    Parameters
    ----------
    out: the run directory.
    command: ``run`` | ``simulate`` | ``fit`` (recorded as ``command``).
    resume, force: as :class:`~motionphysics.io.rundir.RunDirectory`.
    progress: a :class:`~motionphysics.progress.Progress` (timings, display).
    observer: told about stages and the end of the run.
    """

    def __init__(
        self,
        out: str | Path,
        *,
        command: str,
        resume: bool = False,
        force: bool = False,
        progress=None,
        observer: Observer | None = None,
    ):
        from motionphysics.io.rundir import RunDirectory
        from motionphysics.progress import Progress

        self.rd = RunDirectory(out, resume=resume, force=force)
        self.path = self.rd.path
        self.resume = bool(resume)
        if self.resume:
            # temporaries of a killed process are never finished files
            self.rd.clean_temporaries()
        self.command = command
        self.progress = progress or Progress(quiet=True)
        self.observer = observer or NullObserver()
        self.files: list[str] = []
        self.metrics: dict[str, Any] | None = None
        self.plots: list[str] = []
        self.cfg = None
        self._t0 = time.perf_counter()
        self.state: dict[str, Any] = {k: None for k in PARAMS_KEYS}

    # -- lifecycle -----------------------------------------------------------------------
    def begin(self, cfg, *, seed: int, device: str, **extra: Any) -> None:
        """Write ``run.yaml`` and a first ``params.json`` (``partial: true``).

        Resuming, the run there must be one of the same config (``run.yaml``) and the same
        command; a different one is refused (UserInputError naming the first differing
        key) before anything is rewritten (:func:`motionphysics.io.resume.plan_resume`).
        """
        if self.resume and self.rd.holds_run(self.path):
            from motionphysics.io.resume import plan_resume

            plan_resume(self.path, cfg, command=self.command)
        self.state.update(
            {
                "schema": PARAMS_SCHEMA,
                "command": self.command,
                "prompt": cfg.prompt,
                "partial": True,
                "status": "running",
                "stage": "start",
                "seed": int(seed),
                "device": device,
                "versions": versions(),
                "history": [],
                "plots": [],
                "files": [],
                "timings": {},
                **extra,
            }
        )
        self.observer.run_started(self.command, str(self.path))
        self.save_config(cfg)
        self.save()

    def save(self) -> None:
        """Rewrite ``params.json`` from the current state."""
        self.state["timings"] = dict(self.progress.timings)
        self.state["files"] = list(self.files)
        self.rd.write_json("params.json", self.state)

    def save_config(self, cfg) -> None:
        """Rewrite ``run.yaml``: the fully resolved config plus the package versions."""
        from motionphysics.config import config_to_dict

        self.cfg = cfg
        data = config_to_dict(cfg)
        data["versions"] = versions()
        self.rd.write_yaml("run.yaml", data)
        self.add_files("run.yaml", "params.json")

    def add_files(self, *names: str) -> None:
        """Record files written by others in the directory (``log.jsonl`` by the loop)."""
        for n in names:
            if n not in self.files:
                self.files.append(n)

    @contextmanager
    def stage(self, name: str, total: int | None = None) -> Iterator[Any]:
        """A timed stage: ``params.json`` says which stage a killed run was in."""
        self.state["stage"] = name
        self.save()
        self.observer.stage_started(name, total)
        t0 = time.perf_counter()
        with self.progress.stage(name, total) as st:
            yield _ObservedStage(st, name, total, self.observer)
        self.observer.stage_finished(name, time.perf_counter() - t0)
        self.save()

    @contextmanager
    def guard(self) -> Iterator[RunWriter]:
        """Ctrl-C -> ``status: interrupted`` (RunInterrupted); an error -> ``failed``."""
        try:
            yield self
        except KeyboardInterrupt:
            with _no_sigint():
                self.state["status"] = "interrupted"
                self.state["partial"] = True
                self.save()
                self._report()
            self.observer.run_finished("interrupted")
            raise RunInterrupted(
                f"interrupted during '{self.state['stage']}'; {self.path} holds a partial run "
                "(params.json: partial: true); rerun with --resume or --force"
            ) from None
        except BaseException as err:
            self.fail(err)
            raise

    def fail(self, err: BaseException) -> None:
        """Record a failure in ``params.json`` (the original error matters more)."""
        with _no_sigint():
            self.state["status"] = "failed"
            self.state["partial"] = True
            text = (
                f"{type(err).__name__}: {err}".splitlines()[0] if str(err) else type(err).__name__
            )
            self.state["error"] = text
            try:
                self.save()
            except Exception:  # noqa: BLE001 - keep the original error
                pass
        self.observer.run_finished("failed", {"error": self.state["error"]})

    def finish(self, status: str = "complete") -> RunResult:
        """Final ``params.json`` (``partial: false``) and ``report.html``; the result."""
        self.state["partial"] = False
        self.state["status"] = status
        self.state["stage"] = "done"
        self.state["plots"] = list(self.plots)
        self.state["wall_time_s"] = time.perf_counter() - self._t0
        self.save()
        self._report()
        self.add_files("report.html")
        self.save()
        result = RunResult(
            self.path,
            dict(self.state),
            self.metrics,
            dict(self.progress.timings),
            self.path / "video.mp4" if "video.mp4" in self.files else None,
            self.cfg,
            list(self.files),
        )
        self.observer.run_finished(status, self.state)
        return result

    def _report(self) -> None:
        from motionphysics.io.report import optimisation_section_html, write_report

        sections = []
        if self.state.get("history"):
            ranges = _ranges(self.state)
            sections.append(
                optimisation_section_html(
                    self.rd.path,
                    self.state,
                    ranges=ranges or None,
                    initial_video="video_initial.mp4",
                    viewer_command=f"motionphysics view {self.rd.path}",
                )
            )
        write_report(
            self.rd,
            self.state,
            sections=sections,
            prompt=self.state.get("prompt") or "",
            timings=self.state.get("timings"),
            metrics=self.metrics,
            video="video.mp4",
            plots=list(self.plots),
            title=f"motionphysics {self.command}",
        )

    # -- what a run records ------------------------------------------------------------
    def record_grid(self, sim_scene) -> None:
        """The grid of the ``scene`` block as simulated: domain corners, dx, node counts
        (the assembly widens a fitted domain for a material that spreads after
        :meth:`record_scene`)."""
        self.state.setdefault("scene", {}).update(
            {
                "domain_lo": [float(v) for v in _np(sim_scene.domain_lo)],
                "domain_hi": [float(v) for v in _np(sim_scene.domain_hi)],
                "dx": float(sim_scene.dx),
                "grid_dims": [int(v) for v in sim_scene.grid_dims],
            }
        )

    def record_scene(self, cfg, sim_scene) -> None:
        """``scene`` block of params.json and ``scene.ply`` (prepared rest splats; with a
        ``scene.region``, the static splats after them and a per-splat ``simulated`` flag)."""
        from motionphysics.scene.ply import write_ply

        objects = getattr(cfg, "objects", None)
        self.state["scene"] = {
            "source": cfg.scene.source if objects is None else [o.source for o in objects],
            "splats": int(sim_scene.splats.num),
            "particles": int(_np(sim_scene.particles).shape[0]),
            "interior_particles": int(getattr(sim_scene, "n_interior", 0)),
            "domain_lo": [float(v) for v in _np(sim_scene.domain_lo)],
            "domain_hi": [float(v) for v in _np(sim_scene.domain_hi)],
            "dx": float(sim_scene.dx),
            "grid_dims": [int(v) for v in sim_scene.grid_dims],
        }
        if objects is not None and getattr(sim_scene, "object_id", None) is not None:
            counts = np.bincount(_np(sim_scene.object_id).astype(np.int64), minlength=len(objects))
            self.state["scene"]["objects"] = [
                {"name": o.name, "source": o.source, "particles": int(c)}
                for o, c in zip(objects, counts, strict=True)
            ]
        from motionphysics.io.export import with_static

        static = getattr(sim_scene, "static_splats", None)
        if static is not None:
            # scene.region: the static splats follow the simulated ones (flag `simulated`)
            self.state["scene"]["static_splats"] = int(static.num)
        splats, extra = with_static(sim_scene.splats, sim_scene)
        with self.rd.writing("scene.ply") as tmp:
            write_ply(splats, tmp, extra=extra)
        self.add_files("scene.ply")

    def record_camera(self, cfg, note: Mapping[str, Any], image: np.ndarray | None) -> None:
        """``camera`` block, ``plots/reference.png`` (uint8 [H,W,3]) and run.yaml."""
        from motionphysics.config import config_to_dict

        self.state["camera"] = {**note, **config_to_dict(cfg)["camera"]}
        if image is not None:
            self.write_png("plots/reference.png", image)
            if "plots/reference.png" not in self.plots:
                self.plots.insert(0, "plots/reference.png")
        self.save_config(cfg)

    def record_material(
        self, material, sim_values: Mapping[str, Any], sim_context: Mapping[str, Any]
    ) -> None:
        """``class``, ``density``, ``params``, ``units``, ``sim``, ``sim_context``.

        Several objects (``material`` an ``assembly.SceneMaterial``): ``objects: [{name,
        class, class_id, density, params, sim, provenance, particles, initial_velocity}]``
        and the top-level ``class``, ``class_id``, ``density``, ``params`` and ``sim`` null
        (there is no one material); one object: ``objects`` null, layout unchanged."""
        from motionphysics.materials.catalog import class_id

        if getattr(material, "objects", None) is not None:
            self._record_objects(material, sim_context)
            return

        def j(v):
            a = _np(v).astype(np.float64)
            if a.ndim == 0:
                return float(a)
            return {"mean": float(a.mean()), "min": float(a.min()), "max": float(a.max())}

        self.state.update(
            {
                "class": material.cls,
                "class_id": int(class_id(material.cls)),
                "density": j(material.density),
                "params": {k: j(v) for k, v in material.values.items()},
                "units": {k: UNITS.get(k, "") for k in ("density", *material.values)},
                "sim": {k: j(v) for k, v in sim_values.items()},
                "sim_context": dict(sim_context),
            }
        )

    def _record_objects(self, material, sim_context: Mapping[str, Any]) -> None:
        objs = []
        names: list[str] = []
        for o in material.objects:
            m = o.material
            objs.append(
                {
                    "name": o.name,
                    "class": m.cls,
                    "class_id": int(_class_id(m.cls)),
                    "density": float(m.density),
                    "params": {k: float(v) for k, v in m.values.items()},
                    "units": {k: UNITS.get(k, "") for k in ("density", *m.values)},
                    "sim": {k: float(v) for k, v in o.resolution.values.items()},
                    "sim_context": o.resolution.record(),
                    "provenance": o.provenance,
                    "particles": int(o.count),
                    "initial_velocity": [float(v) for v in o.initial_velocity],
                }
            )
            names += [k for k in ("density", *m.values) if k not in names]
        self.state.update(
            {
                "class": None,
                "class_id": None,
                "density": None,
                "params": None,
                "units": {k: UNITS.get(k, "") for k in names},
                "sim": None,
                "sim_context": dict(sim_context),
                "objects": objs,
            }
        )

    # -- files ---------------------------------------------------------------------------
    def write_png(self, name: str, img: np.ndarray) -> None:
        """An RGB uint8 image [H, W, 3] as PNG."""
        from PIL import Image

        with self.rd.writing(name) as tmp:
            Image.fromarray(img).save(tmp, format="PNG")
        self.add_files(name)

    def write_video(self, video: np.ndarray, frame_dt: float, name: str = "video.mp4") -> None:
        """``name`` (default ``video.mp4``) from uint8 frames [T, H, W, 3] at 1 / frame_dt fps."""
        from motionphysics.io.video import write_video

        with self.rd.writing(name) as tmp:
            with _child_stderr_held():
                write_video(video, tmp, _fps(frame_dt))
            # ffmpeg on a full disk prints its complaint and exits, and imageio returns
            # as if all went well, leaving a torn file: check it before it replaces
            # the previous file (an OSError here becomes the one-line OutputError).
            _check_mp4(tmp)
        self.add_files(name)

    def write_trajectory(
        self, sim_scene, xs, Fs, vs, cfg, density, active=None
    ) -> dict[str, np.ndarray]:
        """``trajectory.npz`` (x, t, F, v, masses, volumes, and what re-deforming the
        splats of ``scene.ply`` needs: splat_parent, splat_offset); returns it read back.

        ``density``: kg/m^3, scalar or per particle [P]. Several objects
        (``sim_scene.object_id`` set): also ``object_id [P]`` int64, ``object_names [K]``,
        ``object_mass [K]`` kg. ``active [T, P]`` (the rollout's mask, 0 = removed by a
        cut) is written when given."""
        from motionphysics.io.rundir import read_trajectory, write_trajectory

        frames = xs.shape[0]
        volumes = np.asarray(_np(sim_scene.volumes), dtype=np.float64)
        mass = volumes * np.asarray(_np(density), dtype=np.float64)
        extra: dict[str, np.ndarray] = {}
        oid = getattr(sim_scene, "object_id", None)
        if oid is not None:
            oid = _np(oid).astype(np.int64)
            k = int(oid.max()) + 1
            extra["object_id"] = oid
            extra["object_mass"] = np.bincount(oid, weights=mass, minlength=k).astype(np.float64)
            names = [o.name for o in (getattr(cfg, "objects", None) or [])]
            if len(names) == k:
                extra["object_names"] = np.asarray(names, dtype=str)
        if active is not None:
            extra["active"] = np.asarray(active, dtype=np.float32)
        write_trajectory(
            self.rd.file("trajectory.npz"),
            x=xs,
            t=np.arange(frames, dtype=np.float64) * cfg.sim.frame_dt,
            F=Fs,
            v=vs,
            mass=mass.astype(np.float32),
            volume=volumes.astype(np.float32),
            gravity=np.asarray(cfg.sim.gravity, dtype=np.float32),
            n_visible=np.int64(xs.shape[1] - int(getattr(sim_scene, "n_interior", 0))),
            splat_parent=_np(sim_scene.splat_parent).astype(np.int64),
            splat_offset=_np(sim_scene.splat_offset).astype(np.float32),
            domain_lo=_np(sim_scene.domain_lo).astype(np.float32),
            domain_hi=_np(sim_scene.domain_hi).astype(np.float32),
            dx=np.float32(sim_scene.dx),
            frame_dt=np.float32(cfg.sim.frame_dt),
            **extra,
        )
        self.add_files("trajectory.npz")
        return read_trajectory(self.path / "trajectory.npz")

    def write_metrics(
        self, traj: Mapping[str, np.ndarray], cfg=None, sim_scene=None
    ) -> dict[str, Any]:
        """Physical diagnostics -> ``metrics.json``; the headline values go to params.json.

        With ``cfg`` the elastic energy uses the simulated material and heights are
        measured from the run's ground collider (``metrics.physical``)."""
        material = None
        floor = None
        if self.state.get("class") and self.state.get("sim"):
            material = {"class": self.state["class"], "sim": self.state["sim"]}
        if cfg is not None:
            floor = _floor_height(cfg)
        metrics = write_metrics(self.rd, traj, material, floor=floor)
        self.metrics = metrics
        self.state["metrics"] = {
            k: metrics[k]
            for k in (
                "final_height_ratio",
                "final_extent_ratio",
                "spread_ratio",
                "max_displacement",
                "rebound_ratio",
            )
            if k in metrics
        }
        if metrics.get("objects"):  # the same headline values of each object
            self.state["metrics"]["objects"] = {
                name: {
                    k: m[k]
                    for k in ("final_height_ratio", "spread_ratio", "max_displacement")
                    if k in m
                }
                for name, m in metrics["objects"].items()
            }
        self.add_files("metrics.json")
        return metrics

    def write_outputs(
        self, sim_scene, xs, Fs, vs, video, cfg, material, active=None
    ) -> dict[str, Any]:
        """trajectory.npz, metrics.json and every plot; returns the metrics.

        ``active [T, P]``: the rollout's mask of simulated particles (``Assembly.last_rollout.active``)."""
        traj = self.write_trajectory(sim_scene, xs, Fs, vs, cfg, material.density, active)
        metrics = self.write_metrics(traj, cfg)
        self.write_plots(video, traj, metrics, cfg)
        return metrics

    def write_plots(self, video: np.ndarray, traj, metrics, cfg) -> list[str]:
        """Space-time slices, energy, shape, volume; loss and parameters when optimised."""
        from motionphysics.io.rundir import output_errors

        # matplotlib writes the files itself: a full disk there is one line too
        with output_errors(self.path / "plots", library=True):
            return self._write_plots(video, traj, metrics, cfg)

    def _write_plots(self, video: np.ndarray, traj, metrics, cfg) -> list[str]:
        from motionphysics.io.plots import plot_loss, plot_params, plot_series, space_time_slice

        new: list[str] = []
        row, col = _object_row_col(video[0], cfg.camera.background)
        space_time_slice(
            video,
            self.rd.file("plots/slice_row.png"),
            axis="row",
            index=row,
            frame_dt=cfg.sim.frame_dt,
            title=f"space-time slice, pixel row {row}",
        )
        space_time_slice(
            video,
            self.rd.file("plots/slice_col.png"),
            axis="col",
            index=col,
            frame_dt=cfg.sim.frame_dt,
            title=f"space-time slice, pixel column {col}",
        )
        space_time_slice(
            video,
            self.rd.file("plots/slice.png"),
            frame_dt=cfg.sim.frame_dt,
            title="space-time slice",
        )
        new += ["plots/slice_row.png", "plots/slice_col.png", "plots/slice.png"]
        t = traj["t"]
        plot_series(
            {
                "kinetic": metrics["kinetic_energy"],
                "potential (rel. frame 0)": metrics["potential_energy"],
                "total": metrics["total_energy"],
            },
            t,
            self.rd.file("plots/energy.png"),
            ylabel="energy [J]",
            title="energy",
        )
        plot_series(
            {
                "height / initial": np.asarray(metrics["height"])
                / max(metrics["initial_height"], 1e-9),
                "spread / initial": np.asarray(metrics["spread"]) / max(metrics["spread"][0], 1e-9),
            },
            t,
            self.rd.file("plots/shape.png"),
            ylabel="ratio",
            title="height and spread",
        )
        new += ["plots/energy.png", "plots/shape.png"]
        if "volume_ratio" in metrics:
            vr = metrics["volume_ratio"]
            plot_series(
                {"mean det F": vr["mean"], "min": vr["min"], "max": vr["max"]},
                t,
                self.rd.file("plots/volume.png"),
                ylabel="det F",
                title="volume ratio",
            )
            new.append("plots/volume.png")
        history = self.state.get("history") or []
        if history:
            records = _plot_records(history)
            try:
                plot_loss(records, self.rd.file("plots/loss.png"))
                new.append("plots/loss.png")
            except ValueError:
                pass
            ranges = _ranges(self.state)
            try:
                plot_params(records, ranges, self.rd.file("plots/params.png"))
                new.append("plots/params.png")
            except ValueError:
                pass
        for n in new:
            if n not in self.plots:
                self.plots.append(n)
        self.add_files("plots/")
        return new

    def export_splats(self, sim_scene, xs, Fs, on_frame=None) -> None:
        """``splats/frame_XXXX.ply`` for every frame (``--export-ply``)."""
        from motionphysics.io.export import export_splats
        from motionphysics.io.rundir import output_errors

        with output_errors(self.path / "splats", library=True):
            export_splats(sim_scene, xs, Fs, self.path / "splats", on_frame=on_frame)
        self.add_files("splats/")


class _ObservedStage:
    """A progress stage handle that also tells the observer how far the stage got."""

    def __init__(self, st, name: str, total: int | None, observer: Observer):
        self._st, self.name, self.total, self._observer = st, name, total, observer
        self.done = 0

    def advance(self, n: int = 1) -> None:
        self.done += int(n)
        self._st.advance(n)
        self._observer.stage_advanced(self.name, self.done, self.total)

    def note(self, text: str) -> None:
        self._st.note(text)

    def set_total(self, total: int) -> None:
        self.total = int(total)
        self._st.set_total(total)


def _floor_height(cfg) -> float | None:
    """Height along up of the run's ground collider (a surface collider facing up), if any."""
    g = np.asarray(cfg.sim.gravity, dtype=np.float64)
    if not np.any(g):
        return None
    up = -g / np.linalg.norm(g)
    best = None
    for bc in cfg.boundary_conditions or []:
        if getattr(bc, "type", None) != "surface_collider" or getattr(bc, "mode", None) == "cut":
            continue
        n = np.asarray(bc.normal, dtype=np.float64)
        n = n / (np.linalg.norm(n) or 1.0)
        if float(n @ up) > 0.99:
            h = float(np.asarray(bc.point, dtype=np.float64) @ up)
            best = h if best is None else max(best, h)
    return best


def write_metrics(
    rd, traj: Mapping[str, np.ndarray], material=None, *, floor: float | None = None
) -> dict[str, Any]:
    """Physical diagnostics of ``traj`` -> ``metrics.json`` (flat keys; see metrics.physical)."""
    from motionphysics.metrics.physical import physical_metrics

    metrics = {
        "schema": "motionphysics.metrics/1",
        **physical_metrics(dict(traj), material, floor=floor),
    }
    rd.write_json("metrics.json", metrics)
    return metrics


def _object_row_col(frame0: np.ndarray, background) -> tuple[int, int]:
    """Pixel row and column through the middle of the object in frame 0 (not background)."""
    bg = np.asarray(background, dtype=np.float32) * 255.0
    diff = np.abs(frame0.astype(np.float32) - bg).sum(-1) > 24
    if not diff.any():
        return frame0.shape[0] // 2, frame0.shape[1] // 2
    rows, cols = np.nonzero(diff)
    return int(np.median(rows)), int(np.median(cols))


def _plot_records(history: list[dict]) -> list[dict]:
    """History records with per-particle values reduced to their mean (for the plots)."""
    from motionphysics.io.object_params import flat_params

    out = []
    for r in history:
        params = {}
        for n, v in flat_params(r.get("params") or {}).items():
            if isinstance(v, dict):
                v = v.get("mean")
            if isinstance(v, (int, float)):
                params[n] = v
        out.append({"iteration": r.get("iteration"), "loss": r.get("loss"), "params": params})
    return out


def _ranges(state: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """Handbook ranges of the optimised (or all) parameters of the state's class."""
    from motionphysics.materials.catalog import spec

    opt = state.get("fit") or state.get("optimise") or {}
    names = opt.get("optimised") or list(state.get("params") or {})
    # several objects: OBJECT.PARAM names, each of its object's class
    classes = {o["name"]: o["class"] for o in state.get("objects") or []}
    out = {}
    for n in names:
        obj, _, own = n.rpartition(".") if classes else ("", "", n)
        if own == "density" or own == "initial_velocity":
            continue
        s = spec(classes[obj] if classes else state["class"], own)
        out[n] = (float(s.low), float(s.high))
    return out


# --------------------------------------------------------------------------------------
# the summary
# --------------------------------------------------------------------------------------
def _mean(v: Any) -> float:
    return float(v.get("mean")) if isinstance(v, dict) else float(v)


def format_value(v: Any) -> str:
    """A number as the summary prints it: ``0.3``, ``1000``, ``1.000e+07`` (mean of a field)."""
    if isinstance(v, dict):
        return f"{format_value(v.get('mean'))} (mean)"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    v = float(v)
    a = abs(v)
    return f"{v:.4g}" if (a == 0 or 1e-3 <= a < 1e5) else f"{v:.3e}"


def _objects_summary(
    objects: list[dict[str, Any]], initial: dict[str, Any] | None = None
) -> list[str]:
    """Summary lines of a scene of several objects: one line per object, then its values
    (``start X`` where an optimisation moved one: params.json ``initial.objects``)."""
    lines = []
    for o in objects:
        start = (initial or {}).get(o.get("name")) or {}
        start = {"density": start.get("density"), **(start.get("params") or {})}
        prov = o.get("provenance") or {}
        lines.append(
            f"object:    {o.get('name')}: {o.get('class')} (from {prov.get('backend', '?')}), "
            f"{o.get('particles')} particles"
        )
        sources = prov.get("sources") or {}
        for name, value in {"density": o.get("density"), **(o.get("params") or {})}.items():
            src = sources.get(name)
            line = f"  {name:<10} {format_value(value):>12}"
            if start.get(name) is not None and start[name] != value:
                line += f"  start {format_value(start[name])}"
            lines.append(line + (f"  [{src}]" if src else ""))
    return lines


def summary_text(result: RunResult) -> str:
    """The final summary every command prints: material, parameters, video, timings."""
    p = result.params
    lines = [f"prompt:    {p.get('prompt', '')}"]
    prov = p.get("provenance") or {}
    est = prov.get("estimate") or {}
    if p.get("objects"):
        lines += _objects_summary(p["objects"], (p.get("initial") or {}).get("objects"))
        prov = {}  # each object's provenance is in its own lines
    else:
        how = f"from {prov.get('backend', '?')}"
        if est.get("confidence") is not None:
            how += f", confidence {float(est['confidence']):.2f}"
        if est.get("matched"):
            how += f", matched {est['matched']!r}"
        lines.append(f"material:  {p.get('class')} ({how})")
    sim = p.get("sim") or {}
    units = p.get("units") or {}
    initial = (p.get("initial") or {}).get("params") or {}
    # Simulation values are paired with a physical parameter only when they are the same
    # quantity (simmap.sim_quantities); the others are listed under their own names.
    from motionphysics.materials.simmap import sim_quantities

    rows = (
        sim_quantities(p["class"], {k: _mean(v) for k, v in sim.items()}) if p.get("class") else []
    )
    paired = {r["pairs_with"]: r for r in rows if r["pairs_with"]}
    top = {} if p.get("objects") else {"density": p.get("density"), **(p.get("params") or {})}
    for name, value in top.items():
        s = f"  {name:<10} {format_value(value):>12} {units.get(name, ''):<6}"
        if name in paired:
            s += f"  (simulation: {format_value(paired[name]['value'])})"
        if name in initial:
            s += f"  start {format_value(initial[name])}"
        src = (prov.get("sources") or {}).get(name)
        if src:
            s += f"  [{src}]"
        lines.append(s)
    own = [r for r in rows if not r["pairs_with"]]
    if own:
        lines.append(
            "  simulated as: "
            + ", ".join(f"{r['name']} {format_value(r['value'])} {r['unit']}" for r in own)
        )
    for c in prov.get("clamps") or []:
        kind = c.get("kind", "clamped")
        src = f" ({c['source']})" if c.get("source") else ""
        lines.append(
            f"  {kind} {c['field']}: {format_value(c['original'])} -> "
            f"{format_value(c['clamped'])}{src}"
        )
    scene = p.get("scene") or {}
    # the default ground; the static scene of a region run; why fill: true added nothing
    for key in ("ground", "domain", "static", "static_support", "fill"):
        if scene.get(key):
            lines.append(f"{key}:{' ' * (9 - len(key))} {scene[key].removeprefix(key + ': ')}")
    opt = p.get("fit") or p.get("optimise")
    if opt:
        label = "fit:      " if p.get("fit") else "optimise: "
        lines.append(
            f"{label} {opt.get('message', '')} ({opt.get('loss', '?')}, grad_mode "
            f"{opt.get('grad_mode', '?')})"
        )
        lines += list((opt.get("motion") or {}).get("lines") or [])
    else:  # a run without refinement: the motion asked beside the one simulated
        lines += list(((p.get("metrics") or {}).get("motion") or {}).get("lines") or [])
    m = result.metrics or {}
    if m:
        lines.append(
            "motion:    vertical extent final/initial "
            f"{m.get('final_extent_ratio', m.get('final_height_ratio', float('nan'))):.3f}, "
            f"spread ratio {m.get('spread_ratio', float('nan')):.3f}, "
            f"max displacement {m.get('max_displacement', float('nan')):.3f} m"
        )
    lines.append(f"video:     {result.run_dir / 'video.mp4'}")
    lines.append(f"report:    {result.run_dir / 'report.html'}")
    lines.append("timings:")
    total = 0.0
    for k, v in result.timings.items():
        lines.append(f"  {k:<18} {v:8.2f} s")
        total += v
    lines.append(f"  {'total':<18} {total:8.2f} s")
    return "\n".join(lines)


def print_summary(result: RunResult, stream=None) -> None:
    print(summary_text(result), file=stream or sys.stdout)
