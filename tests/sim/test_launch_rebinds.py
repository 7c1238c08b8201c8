"""``sim.launch.Rebinds``: a launch packed once and re-bound to new arrays and scalars gives
bitwise what ``wp.launch`` gives, forward and adjoint, and packs once per call site."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from motionphysics.runtime import init_warp

wp = init_warp()


@wp.kernel
def _axpy_off(
    x: wp.array(dtype=wp.vec3),
    s: float,
    off: wp.vec3i,
    k: int,
    y: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    o = wp.vec3(float(off[0]), float(off[1]), float(off[2]))
    v = x[i] * s
    y[i] = wp.vec3(wp.sin(v[0]), wp.cos(v[1]), v[2] * v[2]) + o * float(k)


def _arrays(seed: int, n: int = 37, grad: bool = False):
    rng = np.random.default_rng(seed)
    x = wp.array(rng.normal(size=(n, 3)).astype(np.float32), dtype=wp.vec3, requires_grad=grad)
    y = wp.zeros(n, dtype=wp.vec3, requires_grad=grad)
    return x, y


def test_forward_rebinds_arrays_and_scalars_bitwise_and_packs_once():
    from motionphysics.sim.launch import Rebinds

    rb = Rebinds(wp, wp.get_device("cpu"))
    assert rb.enabled
    for seed in range(5):
        x, y = _arrays(seed)
        s, off, k = 0.3 + 0.1 * seed, wp.vec3i(seed, 2, -seed), seed % 2
        rb.launch(_axpy_off, x.shape[0], [x, s, off, k], [y])
        ref = wp.zeros_like(y)
        wp.launch(_axpy_off, dim=x.shape[0], inputs=[x, s, off, k], outputs=[ref], device="cpu")
        assert np.array_equal(y.numpy(), ref.numpy())
        # the same arrays again, a scalar changed in place of the vector
        off2 = wp.vec3i(7, 7, 7)
        rb.launch(_axpy_off, x.shape[0], [x, s, off2, k], [y])
        wp.launch(_axpy_off, dim=x.shape[0], inputs=[x, s, off2, k], outputs=[ref], device="cpu")
        assert np.array_equal(y.numpy(), ref.numpy())
    assert rb.packs == 1  # one call site, one signature
    # another length is another signature: packed once more
    x, y = _arrays(9, n=11)
    rb.launch(_axpy_off, 11, [x, 1.0, wp.vec3i(0, 0, 0), 1], [y])
    assert rb.packs == 2


def test_adjoint_rebinds_bitwise_with_none_adjoints():
    from motionphysics.sim.launch import Rebinds

    rb = Rebinds(wp, wp.get_device("cpu"))
    for seed in range(3):
        outs = []
        for how in ("rebinds", "warp"):
            x, y = _arrays(seed, grad=True)
            y.grad.fill_(wp.vec3(1.0, -2.0, 0.5))
            args = dict(
                inputs=[x, 0.7, wp.vec3i(1, 2, 3), 2],
                outputs=[y],
                adj_inputs=[x.grad, None, None, None],
                adj_outputs=[y.grad],
            )
            if how == "rebinds":
                rb.launch(_axpy_off, x.shape[0], adjoint=True, **args)
            else:
                wp.launch(_axpy_off, dim=x.shape[0], adjoint=True, device="cpu", **args)
            outs.append(x.grad.numpy())
        assert np.abs(outs[0]).sum() > 0
        assert np.array_equal(outs[0], outs[1])
    assert rb.packs == 1


def test_two_threads_get_their_own_packed_launch():
    """Two chunks of a substep launch the same kernel from two threads at once: each has
    its own packed struct (a shared one would race between rebinding and running)."""
    from motionphysics.sim.launch import Rebinds

    rb = Rebinds(wp, wp.get_device("cpu"))
    pairs = [_arrays(s) for s in range(2)]
    errors = []

    def work(c: int) -> None:
        x, y = pairs[c]
        try:
            for r in range(50):
                rb.launch(_axpy_off, x.shape[0], [x, 0.1 * r, wp.vec3i(c, r, 0), c], [y])
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    ts = [threading.Thread(target=work, args=(c,)) for c in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors and rb.packs == 2
    for c, (x, y) in enumerate(pairs):
        ref = wp.zeros_like(y)
        wp.launch(_axpy_off, dim=x.shape[0], inputs=[x, 0.1 * 49, wp.vec3i(c, 49, 0), c],
                  outputs=[ref], device="cpu")  # fmt: skip
        assert np.array_equal(y.numpy(), ref.numpy())


def test_an_argument_it_cannot_rebind_falls_back_to_warp():
    from motionphysics.sim.launch import Rebinds

    rb = Rebinds(wp, wp.get_device("cpu"))
    x, y = _arrays(0)
    with pytest.raises(RuntimeError):  # Warp's own error for a wrong argument type
        rb.launch(_axpy_off, x.shape[0], [x, 0.5, wp.vec3i(0, 0, 0), 1], [[1, 2]])
    assert rb.packs == 0
