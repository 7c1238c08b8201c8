"""The untaped forward of an all-elastic scene runs ``kernels._stress_elastic_p2g`` (stress
and P2G in one pass); it must give the same states as the two launches it replaces."""

import numpy as np
import pytest

from motionphysics.sim import bench as B
from motionphysics.sim.solver import Solver, SolverConfig


@pytest.mark.parametrize("threads", [1, 2])
def test_fused_elastic_p2g_matches_the_two_kernels(threads):
    model, _, x0 = B.build_scene(4000, 24, threads=threads)
    ends = []
    for fuse in (False, True):
        solver = Solver(
            model,
            SolverConfig(threads=threads, min_particles_per_thread=16, fuse_elastic_p2g=fuse),
        )
        a = model.state(x0, B.INITIAL_VELOCITY)
        b = model.state(x0, B.INITIAL_VELOCITY)
        for k in range(40):
            solver.step(a, b, 4.0 * B.DT, t=k * 4.0 * B.DT, substep=k)
            a, b = b, a
        ends.append({n: getattr(a, n).numpy().copy() for n in ("x", "v", "C", "F", "ep")})
    # the same expressions in the same order: equal to float round-off (in practice bitwise)
    for n in ends[0]:
        np.testing.assert_allclose(ends[1][n], ends[0][n], rtol=1e-6, atol=1e-7, err_msg=n)
    assert not np.array_equal(ends[0]["x"], x0)  # it moved
