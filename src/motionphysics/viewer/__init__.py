"""Web viewer (viser) of run directories: the deformed splats over time, in a browser.

``motionphysics view RUN_DIR ...`` (``commands/view.py``) calls :func:`start_view`.
The run directory contract the viewer reads is in :mod:`motionphysics.viewer.rundata`
(``REQUIRED_FILES``, ``REQUIRED_ARRAYS``); frames are deformed by
:mod:`motionphysics.viewer.frames` with the renderer's own ``deform_splats``; the
server and its panel are :mod:`motionphysics.viewer.server` (the only module that
imports viser, which is the optional ``viewer`` extra).
"""

from __future__ import annotations

__all__ = ["load_run", "FrameSource", "Viewer", "start_view"]


def __getattr__(name):  # lazy: importing the package must not import viser or torch
    if name == "load_run":
        from motionphysics.viewer.rundata import load_run

        return load_run
    if name == "FrameSource":
        from motionphysics.viewer.frames import FrameSource

        return FrameSource
    if name in ("Viewer", "start_view"):
        from motionphysics.viewer import server

        return getattr(server, name)
    raise AttributeError(name)
