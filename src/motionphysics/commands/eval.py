"""``motionphysics eval RUN_DIR``: (re)compute ``metrics.json`` from a run's trajectory.

Physical diagnostics (energies, volume ratio, displacement, height and spread ratios,
oscillation) from ``trajectory.npz``; prints the key figures.
"""

from __future__ import annotations


def _main(args) -> int:
    from motionphysics.io.rundir import RunDirectory, read_trajectory
    from motionphysics.pipeline import write_metrics

    rd = RunDirectory(args.run_dir, create=False)
    traj = read_trajectory(rd.path / "trajectory.npz")
    m = write_metrics(rd, traj)
    if not args.quiet:
        print(f"metrics:   {rd.path / 'metrics.json'}")
        print(f"frames {m['frames']}, particles {m['particles']}, duration {m['duration_s']:.3g} s")
        print(
            f"final height / initial {m['final_height_ratio']:.3f}; spread ratio {m['spread_ratio']:.3f}; "
            f"max displacement {m['max_displacement']:.3g} m; max speed {m['max_speed']:.3g} m/s"
        )
        if "volume_ratio" in m:
            vr = m["volume_ratio"]
            print(f"volume ratio det F in [{vr['overall_min']:.3f}, {vr['overall_max']:.3f}]")
    return 0


def register(subparsers) -> None:
    from motionphysics.commands.run import add_display_options

    p = subparsers.add_parser(
        "eval", help="write metrics.json for a run directory", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory (holds trajectory.npz)")
    add_display_options(p)
    p.set_defaults(func=_main)
