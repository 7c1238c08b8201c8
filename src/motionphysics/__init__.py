"""motionphysics: text-guided physical simulation of 3D Gaussian-splat scenes.

The package is organised as docs/ARCHITECTURE.md describes: ``scene`` (load and prepare splats),
``materials`` (catalogue and parameter maps), ``init`` (material estimation from
words), ``sim`` (differentiable MLS-MPM on Warp), ``render`` (differentiable splat
rasteriser), ``optimize`` (the loop, fit, refinement), ``io`` (run directory writer, video, plots);
``assembly`` builds every command's parts, ``pipeline`` runs ``run``/``simulate``.
Importing this package does no work: heavy modules load on first use.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
