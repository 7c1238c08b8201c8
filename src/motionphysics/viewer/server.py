"""The web viewer: a viser server showing the deformed splats of one or more runs.

What a person sees (one browser tab, any number of them):

* the splats of the current frame, computed by
  :class:`~motionphysics.viewer.frames.FrameSource` (the renderer's deformation);
  only the current frame is ever sent to the browser, so a long or large run
  streams frame by frame;
* the ground and the other boundary conditions of ``run.yaml``: surface colliders
  as grids in their planes (the ground grey, walls blue, ``cut`` planes red), the
  simulation domain of a ``bounding_box`` and ``clamp_grid`` regions as wire boxes;
* a timeline (frame slider, play / pause, speed as a multiple of real time, loop),
  the run's camera as the start view and a button back to it;
* a side panel: prompt, material per object with where each value came from, the
  loss and parameter curves of an optimised run, the metrics; with several runs a
  drop-down switches between them.

viser is imported here only (the ``viewer`` extra); nothing else of the package
imports this module at import time. Covariances travel as float16 in viser's
buffer, too coarse for millimetre splats, so each run's splats are sent in units
of their median size (the scene node carries the inverse scale): the picture is the
same, the precision is relative.
"""

from __future__ import annotations

import contextlib
import io
import math
import socket
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError
from motionphysics.viewer.frames import DEFAULT_MAX_SPLATS, FrameSource, is_large

__all__ = ["Viewer", "ServedFrame", "check_port_free", "start_view"]

SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
"""Playback speeds offered, as multiples of real time (1 = ``frame_dt`` per frame)."""


def check_port_free(host: str, port: int) -> None:
    """Raise UserInputError (one line) when ``host:port`` cannot be bound.

    viser would silently move to the next free port; a user who asked for a port
    must get that port or an error.
    """
    if not 0 < int(port) < 65536:
        raise UserInputError(f"--port: expected 1..65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as err:
        raise UserInputError(f"--host: cannot resolve {host!r} ({err.strerror})") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        # As the server will bind (SO_REUSEADDR): a port in TIME_WAIT is free, a listener is not.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as err:
            if err.errno in (98, 48, 10048):  # EADDRINUSE on Linux, macOS, Windows
                raise UserInputError(
                    f"--port: port {port} on {host} is already in use; choose another with --port"
                ) from None
            raise UserInputError(
                f"--host/--port: cannot bind {host}:{port} ({err.strerror})"
            ) from None


@dataclass(frozen=True)
class ServedFrame:
    """What the browser was last sent, decoded from viser's buffer (world units).

    ``means [M, 3]`` m (float32 exact), ``covs [M, 3, 3]`` m² (float16 relative
    precision), ``colors [M, 3]`` and ``opacities [M]`` in [0, 1] (8-bit).
    """

    run: int
    index: int
    means: np.ndarray
    covs: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray


def _quat_z_to(n: np.ndarray) -> tuple[float, float, float, float]:
    """wxyz quaternion rotating +z onto the unit vector ``n``."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ n)
    if c < -1 + 1e-9:
        return (0.0, 1.0, 0.0, 0.0)
    axis = np.cross(z, n)
    w = math.sqrt(0.5 * (1.0 + c))
    xyz = axis / (2.0 * w)
    return (w, float(xyz[0]), float(xyz[1]), float(xyz[2]))


def _box_edges(lo, hi) -> np.ndarray:
    """The 12 edges of an axis-aligned box as line segments ``[12, 2, 3]``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    return np.stack([np.stack([c[i], c[j]]) for i, j in pairs])


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if v == 0 or not math.isfinite(v):
            return str(v)
        a = abs(v)
        return f"{v:.4g}" if 1e-3 <= a < 1e5 else f"{v:.3e}"
    return str(v)


def _md_escape(text: str) -> str:
    # Characters that change meaning anywhere in a line (tables included).
    return "".join("\\" + ch if ch in "\\`*_{}[]<>#|" else ch for ch in str(text))


def material_markdown(params: dict[str, Any]) -> str:
    """Material per object (class, density, parameters SI / simulation, provenance)."""
    objects = params.get("objects")
    if isinstance(objects, list) and objects:
        entries = [(str(o.get("name", f"object {i}")), o) for i, o in enumerate(objects)]
    else:
        entries = [("object", params)]
    out = []
    for name, rec in entries:
        prov = rec.get("provenance") or params.get("provenance") or {}
        sources = prov.get("sources") or {}
        phys = {"density": rec.get("density"), **(rec.get("params") or {})}
        sim = rec.get("sim") or {}
        out.append(
            f"**{_md_escape(name)}**: {_md_escape(rec.get('class', '?'))}, estimated by "
            f"{_md_escape(prov.get('backend', '?'))}"
        )
        out.append("")
        out.append("| parameter | SI | simulation | from |")
        out.append("|---|---|---|---|")
        for k, v in phys.items():
            out.append(
                f"| {_md_escape(k)} | {_fmt(v)} | {_fmt(sim.get(k))} | "
                f"{_md_escape(sources.get(k, ''))} |"
            )
        for c in prov.get("clamps") or []:
            out.append("")
            out.append(
                f"clamped {_md_escape(c.get('field'))}: {_fmt(c.get('original'))} → "
                f"{_fmt(c.get('clamped'))}"
            )
        out.append("")
    return "\n".join(out)


def metrics_markdown(metrics: dict[str, Any]) -> str:
    """Scalar metrics (nested dicts flattened one level) as a table."""
    rows = []
    for k, v in metrics.items():
        if k == "schema":
            continue
        if isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, int | float) and not isinstance(vv, bool):
                    rows.append((f"{k}.{kk}", vv))
        elif isinstance(v, int | float) and not isinstance(v, bool):
            rows.append((k, v))
    if not rows:
        return "no scalar metrics"
    return "\n".join(
        ["| metric | value |", "|---|---|"] + [f"| {_md_escape(k)} | {_fmt(v)} |" for k, v in rows]
    )


def history_series(history: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Curves of an optimisation history: ``iteration`` and ``loss`` plus one per parameter.

    Values are float64 ``[I]`` (NaN where a record lacks them); parameters come from
    each record's ``params`` (physical units, SI).
    """
    from motionphysics.io.object_params import flat_params

    # several objects: each object's values as OBJECT.PARAM curves
    history = [{**r, "params": flat_params(r.get("params") or {})} for r in history]
    its = np.array([float(r.get("iteration", i)) for i, r in enumerate(history)], dtype=np.float64)
    out: dict[str, np.ndarray] = {"iteration": its}

    def col(get) -> np.ndarray:
        vals = []
        for r in history:
            try:
                v = get(r)
                vals.append(float(v) if v is not None else math.nan)
            except (TypeError, ValueError, KeyError):
                vals.append(math.nan)
        return np.array(vals, dtype=np.float64)

    out["loss"] = col(lambda r: r.get("loss"))
    names: list[str] = []
    for r in history:
        for k in r.get("params") or {}:
            if k not in names:
                names.append(k)
    for k in names:
        out[f"param:{k}"] = col(lambda r, k=k: (r.get("params") or {}).get(k))
    return out


def _camera_view(cfg) -> dict[str, Any]:
    """Start view of a run config's camera: position, look_at, up, vertical fov [rad]."""
    from motionphysics.render.camera import camera_from_config
    from motionphysics.scene.prepare import scene_transform

    # a capture's cameras follow the scene transform (of the first object, as the run's)
    scene = cfg.objects[0] if cfg.objects else cfg.scene
    cam = camera_from_config(cfg.camera, scene_transform(scene))
    pos = cam.position.numpy()
    R = cam.rotation.numpy()  # rows: right, down, forward
    if cfg.camera.camera_file:
        look_at = pos + R[2] * float(cfg.camera.radius)
    else:
        look_at = np.asarray(cfg.camera.look_at, dtype=np.float64)
    fov = 2.0 * math.atan(0.5 * cam.height / cam.fy)
    return {"camera": cam, "position": pos, "look_at": look_at, "up": -R[1], "fov": fov}


class _RunView:
    """Per-run state of the viewer: its frame source, scene nodes and panel."""

    def __init__(self, run, max_splats: int | None):
        self.run = run
        self.view = _camera_view(run.config)
        self.source = FrameSource(run, self.view["camera"], max_splats=max_splats)
        sc = run.splats.scales.detach().numpy()
        # Unit of the covariance buffer (see module docstring).
        self.unit = float(np.median(sc.max(axis=1))) if sc.size else 1.0
        if not (self.unit > 0 and math.isfinite(self.unit)):
            self.unit = 1.0
        pts = run.splats.means.detach().numpy().astype(np.float64)
        if pts.shape[0]:
            self.lo, self.hi = np.percentile(pts, 0.5, axis=0), np.percentile(pts, 99.5, axis=0)
        else:
            self.lo = self.hi = np.zeros(3)
        self.size = max(float(np.max(self.hi - self.lo)), 1e-3)
        self.large = is_large(run.num_splats, run.num_frames)
        self.nodes: list[Any] = []
        self.folder = None
        self.plots: dict[str, Any] = {}  # curve name ("loss", "param:E") -> uplot handle

    def streaming_note(self) -> str:
        r = self.run
        note = (
            f"{r.num_splats} splats × {r.num_frames} frames; "
            "frames are computed on the server and streamed one at a time when shown "
            "(never all frames at once)"
        )
        if self.source.subsampled:
            note += (
                f"; showing {self.source.num_shown} of {r.num_splats} splats "
                "(a fixed random subset, the same in every frame; --max-splats)"
            )
        return note


class Viewer:
    """A viser server over one or more runs (see the module docstring).

    Args:
        runs: :class:`~motionphysics.viewer.rundata.RunData`, at least one.
        host, port: where to listen (the port must be free).
        frame: the frame shown first.
        max_splats: subsample runs with more splats than this (None: never).
        out: where the URL and notes are printed.
    """

    def __init__(
        self,
        runs,
        host: str = "127.0.0.1",
        port: int = 8080,
        frame: int = 0,
        max_splats: int | None = DEFAULT_MAX_SPLATS,
        out=None,
    ):
        if not runs:
            raise UserInputError("view: expected at least one RUN_DIR")
        self.host, self.port = host, int(port)
        self.out = out if out is not None else sys.stdout
        self.views = [_RunView(r, max_splats) for r in runs]
        for v in self.views:
            T = v.run.num_frames
            if not 0 <= int(frame) < T:
                raise UserInputError(
                    f"--frame: expected 0..{T - 1} for {v.run.path} ({T} frames), got {frame}"
                )
        self.start_frame = int(frame)
        self.server = None
        self.current = 0
        self._frame = self.start_frame
        self._served: ServedFrame | None = None
        self._splat_handle = None
        self._show_lock = threading.Lock()
        self._stop = threading.Event()
        self._playing = threading.Event()
        self._player: threading.Thread | None = None

    # ---- life cycle ------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    def start(self) -> str:
        """Bind, build the scene and the panel, print the URL; returns the URL."""
        import viser

        check_port_free(self.host, self.port)
        # viser prints its own banner; ours (below) says the same and what is shown.
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(
                host=self.host, port=self.port, label="motionphysics", verbose=False
            )
        if int(self.server.get_port()) != self.port:
            # Another process took the port between our check and viser's bind.
            self.server.stop()
            self.server = None
            raise UserInputError(
                f"--port: port {self.port} on {self.host} is already in use; choose another with --port"
            )
        self.server.scene.world_axes.visible = False
        self._build_gui()
        self._build_scene_nodes()

        @self.server.on_client_connect
        def _(client) -> None:  # called once the client has reported its canvas size
            v = self.views[self.current]
            cc = client.camera
            fov = self.client_fov(v.view, cc.image_width, cc.image_height)
            if abs(fov - float(v.view["fov"])) > 1e-6:
                cc.fov = fov

        self.select_run(0)
        self._player = threading.Thread(target=self._play_loop, name="mp-view-play", daemon=True)
        self._player.start()
        names = ", ".join(str(v.run.path) for v in self.views)
        print(f"motionphysics view: {names}", file=self.out)
        for v in self.views:
            if v.large or v.source.subsampled:
                print(
                    f"motionphysics view: {v.run.name}: large run: {v.streaming_note()}",
                    file=self.out,
                )
        print(f"motionphysics view: open {self.url}  (Ctrl-C stops)", file=self.out, flush=True)
        return self.url

    def stop(self) -> None:
        self._stop.set()
        self._playing.clear()
        if self._player is not None:
            self._player.join(timeout=2.0)
        if self.server is not None:
            server, self.server = self.server, None
            server.stop()

    def wait(self) -> None:
        """Block until :meth:`stop` (or Ctrl-C in the caller)."""
        while not self._stop.wait(0.5):
            pass

    # ---- scene -----------------------------------------------------------------------
    @staticmethod
    def _up_direction(view: _RunView) -> tuple[float, float, float]:
        g = np.asarray(view.run.config.sim.gravity, dtype=np.float64)
        n = float(np.linalg.norm(g))
        up = -g / n if n > 0 else np.array([0.0, 0.0, 1.0])
        return tuple(float(v) for v in up)

    def _build_scene_nodes(self) -> None:
        """Colliders, domain and regions of every run (hidden unless its run is shown)."""
        from motionphysics.config import BoundingBox, ClampGrid, SurfaceCollider

        scene = self.server.scene
        for i, v in enumerate(self.views):
            cfg = v.run.config
            up = np.asarray(self._up_direction(v))
            centre = 0.5 * (v.lo + v.hi)
            ground_done = False
            for j, bc in enumerate(cfg.boundary_conditions or []):
                name = f"/run{i}/bc{j}"
                if isinstance(bc, SurfaceCollider):
                    n = np.asarray(bc.normal, dtype=np.float64)
                    n = n / max(float(np.linalg.norm(n)), 1e-12)
                    p0 = np.asarray(bc.point, dtype=np.float64)
                    # The grid's centre: the object's centre projected onto the plane.
                    c = centre - float((centre - p0) @ n) * n
                    is_ground = float(n @ up) > 0.7 and bc.mode != "cut" and not ground_done
                    ground_done = ground_done or is_ground
                    colour = (
                        (200, 60, 60)
                        if bc.mode == "cut"
                        else (150, 150, 150)
                        if is_ground
                        else (90, 130, 200)
                    )
                    width = 6.0 * v.size
                    v.nodes.append(
                        scene.add_grid(
                            name,
                            width=width,
                            height=width,
                            plane="xy",
                            cell_size=v.size / 4,
                            section_size=v.size,
                            cell_color=colour,
                            section_color=tuple(int(0.7 * k) for k in colour),
                            plane_color=(235, 235, 235) if is_ground else colour,
                            plane_opacity=0.35 if is_ground else 0.12,
                            wxyz=_quat_z_to(n),
                            position=tuple(float(k) for k in c),
                            visible=False,
                        )
                    )
                elif isinstance(bc, BoundingBox):
                    box = self._domain(v)
                    if box is not None:
                        v.nodes.append(
                            scene.add_line_segments(
                                name,
                                _box_edges(*box),
                                colors=(120, 140, 170),
                                thickness=1.5,
                                thickness_units="screen",
                                visible=False,
                            )
                        )
                elif isinstance(bc, ClampGrid):
                    v.nodes.append(
                        scene.add_line_segments(
                            name,
                            _box_edges(*bc.box),
                            colors=(230, 140, 30),
                            thickness=2.0,
                            thickness_units="screen",
                            visible=False,
                        )
                    )

    @staticmethod
    def _domain(v: _RunView):
        sc = v.run.params.get("scene") or {}
        if "domain_lo" in sc and "domain_hi" in sc:
            return sc["domain_lo"], sc["domain_hi"]
        if v.run.config.sim.domain is not None:
            return v.run.config.sim.domain
        return None

    def select_run(self, i: int) -> None:
        """Show run ``i`` (its splats, colliders, panel, timeline range, start view)."""
        i = int(i)
        prev = self.current
        self.current = i
        v = self.views[i]
        for j, w in enumerate(self.views):
            for node in w.nodes:
                node.visible = j == i
            if w.folder is not None:
                w.folder.visible = j == i
        T = v.run.num_frames
        self._gui_frame.max = max(T - 1, 1) if T > 1 else 1
        self._gui_frame.disabled = T <= 1
        self._frame = min(self._frame, T - 1)
        if self._splat_handle is not None and prev != i:
            self._splat_handle.remove()
            self._splat_handle = None
        self.server.scene.set_up_direction(self._up_direction(v))
        self._set_start_view(v)
        self.show_frame(self._frame)

    def _set_start_view(self, v: _RunView) -> None:
        ic = self.server.initial_camera
        ic.position = tuple(v.view["position"])
        ic.look_at = tuple(v.view["look_at"])
        ic.up = tuple(v.view["up"])
        ic.fov = float(v.view["fov"])
        ic.far = float(max(1000.0, 100 * np.linalg.norm(v.view["position"] - v.view["look_at"])))

    @staticmethod
    def client_fov(view: dict[str, Any], width: int, height: int) -> float:
        """Vertical fov [rad] for a canvas ``width x height`` showing all the run camera sees.

        viser's fov is vertical: a canvas narrower than the run camera's image would
        crop its sides, so the vertical fov widens until the horizontal one matches.
        """
        cam = view["camera"]
        fov = float(view["fov"])
        aspect_cam = cam.width / cam.height
        if width > 0 and height > 0 and width / height < aspect_cam:
            fov = 2.0 * math.atan(math.tan(0.5 * fov) * aspect_cam / (width / height))
        return min(fov, math.radians(170.0))

    def reset_camera(self, client) -> None:
        """Put ``client``'s camera at the run camera (start view)."""
        v = self.views[self.current]
        cc = client.camera
        with client.atomic():
            cc.up_direction = tuple(v.view["up"])
            cc.position = tuple(v.view["position"])
            cc.look_at = tuple(v.view["look_at"])
            cc.fov = self.client_fov(v.view, cc.image_width, cc.image_height)

    def show_frame(self, k: int) -> None:
        """Compute frame ``k`` of the current run and send it (only it) to the browsers."""
        v = self.views[self.current]
        k = int(min(max(int(k), 0), v.run.num_frames - 1))
        self._frame = k
        with self._show_lock:
            if self._frame != k:  # a newer request came in while we waited
                return
            fr = v.source.frame(k)
            s = v.unit
            means = fr.means / s
            covs = fr.covs / (s * s)
            if self._splat_handle is None:
                self._splat_handle = self.server.scene.add_gaussian_splats(
                    f"/run{self.current}/splats",
                    centers=means,
                    covariances=covs,
                    rgbs=fr.colors,
                    opacities=fr.opacities,
                    scale=s,
                )
            else:
                self._splat_handle.set_gaussians(means, covs, fr.colors, fr.opacities)
            buf = self._splat_handle.buffer
            self._served = ServedFrame(
                self.current,
                k,
                buf[:, 0:3].view(np.float32) * np.float32(s),
                self._decode_covs(buf) * (s * s),
                buf[:, 7:8].view(np.uint8).reshape(-1, 4)[:, :3] / 255.0,
                buf[:, 7:8].view(np.uint8).reshape(-1, 4)[:, 3] / 255.0,
            )
        t = float(v.run.t[k])
        self._gui_time.value = f"{t:.3f} s  (frame {k} of {v.run.num_frames - 1})"
        if self._gui_frame.value != k:
            self._gui_frame.value = k

    @staticmethod
    def _decode_covs(buf: np.ndarray) -> np.ndarray:
        tri = np.ascontiguousarray(buf[:, 4:7]).view(np.float16).astype(np.float64)  # [M, 6]
        a, b, c, d, e, f = (tri[:, i] for i in range(6))
        return np.stack(
            [np.stack([a, b, c], -1), np.stack([b, d, e], -1), np.stack([c, e, f], -1)], -2
        )

    def served_frame(self) -> ServedFrame | None:
        """The frame last sent to the browsers, decoded (for tests and diagnostics)."""
        return self._served

    # ---- timeline --------------------------------------------------------------------
    def _play_loop(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            if not self._playing.wait(0.2):
                next_t = time.monotonic()
                continue
            v = self.views[self.current]
            dt = v.run.frame_dt / float(self._gui_speed.value)
            next_t += dt
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()  # slower than real time: show frames as they come
            if not self._playing.is_set():
                continue
            k = self._frame + 1
            if k >= v.run.num_frames:
                if not self._gui_loop.value:
                    self._set_playing(False)
                    continue
                k = 0
            try:
                self.show_frame(k)
            except Exception as err:  # keep the server alive; say what happened
                print(f"motionphysics view: frame {k}: {err}", file=sys.stderr)
                self._set_playing(False)

    def _set_playing(self, on: bool) -> None:
        import viser

        if on:
            self._playing.set()
        else:
            self._playing.clear()
        self._gui_play.label = "Pause" if on else "Play"
        self._gui_play.icon = viser.Icon.PLAYER_PAUSE if on else viser.Icon.PLAYER_PLAY

    # ---- panel -----------------------------------------------------------------------
    def _build_gui(self) -> None:
        import viser

        gui = self.server.gui
        gui.configure_theme(control_width="medium", show_share_button=False)
        # Docked, the panel sits beside the canvas instead of over it, so the start
        # view (the run camera, object in the middle) is never hidden behind it.
        gui.main_panel.dock_right()
        if len(self.views) > 1:
            labels = [f"{i}: {v.run.name}" for i, v in enumerate(self.views)]
            self._gui_run = gui.add_dropdown("Run", labels, initial_value=labels[0])

            @self._gui_run.on_update
            def _(_event) -> None:
                self.select_run(labels.index(self._gui_run.value))

        with gui.add_folder("Timeline"):
            T0 = self.views[0].run.num_frames
            self._gui_frame = gui.add_slider(
                "Frame", min=0, max=max(T0 - 1, 1), step=1, initial_value=self.start_frame
            )
            self._gui_time = gui.add_text("Time", initial_value="", disabled=True)
            self._gui_play = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY)
            self._gui_speed = gui.add_dropdown(
                "Speed ×", [str(s) for s in SPEEDS], initial_value="1.0"
            )
            self._gui_loop = gui.add_checkbox("Loop", initial_value=True)
        reset = gui.add_button("Reset view (run camera)", icon=viser.Icon.CAMERA)

        @self._gui_frame.on_update
        def _(_event) -> None:
            if int(self._gui_frame.value) != self._frame:
                self.show_frame(int(self._gui_frame.value))

        @self._gui_play.on_click
        def _(_event) -> None:
            self._set_playing(not self._playing.is_set())

        @reset.on_click
        def _(event) -> None:
            if event.client is not None:
                self.reset_camera(event.client)

        for i, v in enumerate(self.views):
            v.folder = gui.add_folder(f"Run {i}: {v.run.name}", visible=i == 0)
            with v.folder:
                self._build_run_panel(v)

    def _build_run_panel(self, v: _RunView) -> None:
        gui = self.server.gui
        r = v.run
        gui.add_markdown(f"**Prompt:** {_md_escape(r.prompt)}")
        status = r.params.get("status", "?")
        cmd = r.params.get("command", "?")
        gui.add_markdown(
            f"{_md_escape(cmd)}, {_md_escape(status)}; {r.num_frames} frames of "
            f"{r.frame_dt:.4g} s; {v.streaming_note()}"
        )
        with gui.add_folder("Material", expand_by_default=True):
            gui.add_markdown(material_markdown(r.params))
        history = r.history()
        if history:
            with gui.add_folder("Optimisation", expand_by_default=True):
                series = history_series(history)
                its = series["iteration"]
                opt = r.params.get("optimise") or {}
                gui.add_markdown(
                    f"{len(history)} iterations"
                    + (
                        f"; stopped: {_md_escape(opt.get('stop_reason'))}"
                        if opt.get("stop_reason")
                        else ""
                    )
                )
                for key, ys in series.items():
                    if key == "iteration" or not np.isfinite(ys).any():
                        continue
                    label = key.split(":", 1)[-1]
                    v.plots[key] = gui.add_uplot(
                        data=(its, ys),
                        series=(
                            {"label": "iteration"},
                            {"label": label, "stroke": "#2a6", "width": 2},
                        ),
                        title=label if key == "loss" else f"{label} (SI)",
                        aspect=2.0,
                    )
        if r.metrics:
            with gui.add_folder("Metrics", expand_by_default=False):
                gui.add_markdown(metrics_markdown(r.metrics))


def start_view(
    run_dirs,
    host: str = "127.0.0.1",
    port: int = 8080,
    frame: int = 0,
    max_splats: int | None = DEFAULT_MAX_SPLATS,
    out=None,
    object_name: str | None = None,
) -> Viewer:
    """Load the runs, start the viewer, print its URL; returns the running :class:`Viewer`.
    ``object_name``: show only that object of runs of several objects."""
    from motionphysics.viewer.rundata import load_run

    notes: list[str] = []
    runs = [load_run(p, notes, object_name) for p in run_dirs]
    for line in notes:
        print(f"motionphysics view: {line}", file=out if out is not None else sys.stdout)
    viewer = Viewer(runs, host=host, port=port, frame=frame, max_splats=max_splats, out=out)
    viewer.start()
    return viewer
