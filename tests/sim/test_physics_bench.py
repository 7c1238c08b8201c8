"""The MPM benchmark scene (``motionphysics bench mpm``) integrates the physics it claims.

Before the cube reaches a wall, its centre of mass is in free fall: internal (elastic)
forces cancel in the sum over particles (momentum conservation of the P2G/G2P
transfers), so z_c(t) = z_0 + v_0 t - g t^2 / 2 and v_c(t) = v_0 - g t exactly
(Newton's second law for the whole body), to float32 round-off.
"""

from __future__ import annotations

import json
import math

from motionphysics.cli import main
from motionphysics.sim import bench


def test_bench_scene_centre_of_mass_is_in_free_fall():
    substeps = 100
    res = bench.time_mpm(particles=1000, grid=64, substeps=substeps, repeats=1)
    assert res["particles"] == 1000
    t = substeps * bench.DT
    z0 = bench.CUBE_LOWER_Z + bench.CUBE_SIDE / 2
    v0, g = bench.INITIAL_VELOCITY[2], -bench.GRAVITY[2]
    # 0.02 m of fall from 0.15 m: no particle comes within the 3 wall cells (0.047 m).
    assert math.isclose(res["com_z_end"], z0 + v0 * t - 0.5 * g * t * t, abs_tol=2e-5), res
    assert math.isclose(res["vz_mean_end"], v0 - g * t, abs_tol=1e-4), res
    assert res["particle_substeps_per_s"] > 0


def test_bench_cli_json_with_backward(capsys):
    rc = main(
        [
            "bench",
            "mpm",
            "--particles",
            "512",
            "--substeps",
            "4",
            "--repeats",
            "1",
            "--backward",
            "--frames",
            "2",
            "--json",
        ]
    )
    assert rc == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["target"] == "mpm" and res["particles"] == 512 and res["frames"] == 2
    assert res["grad_E_finite"] and res["backward_particle_substeps_per_s"] > 0
    assert res["peak_rss_mb"] > 0
    # forward runs cover the same frames x substeps and alternate with the backward ones
    assert len(res["backward_over_forward_pairs"]) == 1
    want = res["backward_seconds_median"] / res["seconds_median"]
    assert math.isclose(res["backward_over_forward"], want, rel_tol=1e-12)
    assert math.isclose(
        res["particle_substeps_per_s"], 512 * 4 * 2 / res["seconds_median"], rel_tol=1e-12
    )


def test_bench_cli_rejects_bad_arguments(capsys):
    assert main(["bench", "mpm", "--grid", "8"]) == 2
    assert "--grid" in capsys.readouterr().err
