"""Gaussian scenes in: loading (INRIA 3DGS ply, meshes, builtins) and preparation for MPM.

Public API::

    load_scene(source) -> GaussianScene        builtin:NAME | 3DGS .ply | mesh file
    prepare(scene, scene_cfg, sim_cfg, boundary_conditions) -> SimScene
    read_ply / write_ply, list_builtins, GaussianScene, SimScene

Heavy imports (trimesh, plyfile, scipy) happen inside the functions that need them.
``motionphysics.scene.prepare`` is the function; its module is importable by its
dotted name as usual.
"""

from __future__ import annotations

from pathlib import Path

from motionphysics.errors import UserInputError
from motionphysics.scene.builtin import list_builtins
from motionphysics.scene.gaussians import GaussianScene
from motionphysics.scene.ply import read_ply, write_ply

# The function shadows the submodule of the same name on this package; import the
# module itself as ``from motionphysics.scene.prepare import ...`` (works either way).
from motionphysics.scene.prepare import SimScene, prepare  # noqa: E402  (after the above)

__all__ = [
    "GaussianScene",
    "SimScene",
    "load_scene",
    "prepare",
    "read_ply",
    "write_ply",
    "list_builtins",
]

BUILTIN_PREFIX = "builtin:"


def load_scene(source: str, shade: bool = True) -> GaussianScene:
    """Load a scene in the world frame as stored (no transform applied).

    ``shade`` (run config ``scene.shade``): a mesh without colours or texture gets a
    baked default-light shading (:mod:`motionphysics.scene.mesh`) instead of flat grey.

    ``source`` is ``builtin:NAME``, an INRIA 3DGS ``.ply``, a mesh ``.ply`` (has faces or
    no ``f_dc_*``), or a mesh ``.obj .stl .off .glb .gltf``. Problems a user can fix raise
    UserInputError with one line naming the source.
    """
    from motionphysics.scene import builtin, mesh, ply

    if not isinstance(source, str) or not source.strip():
        raise UserInputError(
            "scene.source: expected 'builtin:NAME' or a path to a .ply or mesh file"
        )
    if source.startswith(BUILTIN_PREFIX):
        return builtin.build_builtin(source[len(BUILTIN_PREFIX) :])
    path = Path(source).expanduser()
    ext = path.suffix.lower()
    if ext not in mesh.MESH_EXTENSIONS:
        raise UserInputError(
            f"{source}: unsupported scene file extension {ext or '(none)'!r}; expected "
            f".ply (3DGS or mesh), {', '.join(e for e in mesh.MESH_EXTENSIONS if e != '.ply')}, "
            "or builtin:NAME"
        )
    if not path.is_file():
        raise UserInputError(f"{source}: scene file not found")
    if ext == ".ply" and ply.ply_kind(path) == "gaussians":
        return ply.read_ply(path)
    return mesh.load_mesh(path, shade=shade)
