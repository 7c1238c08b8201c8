"""Outputs: video files, per-frame splat export, the run directory, report and plots.

Submodules are imported directly (``motionphysics.io.rundir`` ...); importing this
package does no work.
"""
