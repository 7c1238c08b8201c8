"""motionphysics: text-guided physical simulation of 3D Gaussian-splat scenes.

The package is organised as DESIGN.md lays out: ``scene`` (load and prepare splats),
``materials`` (catalogue and parameter maps), ``init`` (material estimation from
words), ``sim`` (differentiable MLS-MPM on Warp), ``render`` (differentiable splat
rasteriser), ``optimize`` (the loop), ``io`` (run directory, video, plots).
Importing this package does no work: heavy modules load on first use.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
