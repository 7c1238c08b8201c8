"""``sds``: dL/dz0 is exactly w(t)(ε̂ − ε) (DreamPhysics' detached-target form), the value
on hand-made tensors, a finite-difference check through the tiny VAEs, and two
iterations end to end on both diffusers priors."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "priors"))

from loss_helpers import (
    build,
    call,
    fd_check_pixel,
    moving_edge,
    tiny_prior,
    two_iterations_move_theta,
)  # noqa: E402

from motionphysics.losses import LOSSES  # noqa: E402
from motionphysics.losses.sds import SdsLoss  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.mark.parametrize("ptype", ["epsilon", "v_prediction"])
@pytest.mark.parametrize("form", ["sds", "classifier_score"])
def test_gradient_wrt_latent_is_weighted_residual(ptype, form):
    prior = tiny_prior("analytic", prediction_type=ptype)
    loss = build("sds", prior, guidance=7.5, form=form)
    rgb = moving_edge(torch.tensor(0.3), 4, 8).requires_grad_(True)
    captured = {}
    real_encode = prior.encode

    def encode(frames, generator=None):
        z = real_encode(frames)
        z.retain_grad()
        captured["z"] = z
        return z

    prior.encode = encode
    try:
        value = call(loss, rgb, seed=4)
    finally:
        del prior.encode
    value.backward()
    z = captured["z"]
    # by hand from the same draws
    rng = torch.Generator().manual_seed(4)
    t = torch.randint(20, 981, (1,), generator=rng)
    eps = torch.randn(z.shape, generator=rng)
    a = prior.alphas_cumprod[t]
    zt = a.sqrt() * z.detach() + (1 - a).sqrt() * eps
    tx = prior.text
    out_u, out_c = prior.model_output(zt, t, tx.uncond), prior.model_output(zt, t, tx.cond)
    out = out_u + 7.5 * (out_c - out_u)
    if ptype == "epsilon":
        e_hat, e_u = out, out_u
    else:
        e_hat, e_u = a.sqrt() * out + (1 - a).sqrt() * zt, a.sqrt() * out_u + (1 - a).sqrt() * zt
    grad = (1 - a) * (e_hat - (eps if form == "sds" else e_u))
    torch.testing.assert_close(z.grad, grad, rtol=1e-5, atol=1e-6)
    assert float(value) == pytest.approx(0.5 * float((grad**2).sum()), rel=1e-5)
    assert loss.components()["w"] == pytest.approx(float(1 - a))


def test_registry_defaults():
    assert LOSSES.get("sds") is SdsLoss
    o = LOSSES.options("sds", {})
    assert (o.guidance, o.t_min, o.t_max, o.weighting) == (100.0, 20, 980, "sds")


@pytest.mark.parametrize("kind", ["cogvideox", "modelscope"])
def test_gradient_matches_finite_differences(kind):
    """The surrogate's pixel gradient against central differences of <sg(grad), E(x)>."""
    prior = tiny_prior(kind, dtype="float64")
    loss = build("sds", prior, guidance=5.0)
    rgb = moving_edge(
        torch.tensor(0.3, dtype=torch.float64), prior.num_frames, 16, dtype=torch.float64
    )
    frozen = {}
    real_predict = prior.predict

    def predict(z_t, t, guidance):
        if "p" not in frozen:
            frozen["p"] = real_predict(z_t, t, guidance)
        return frozen["p"]

    prior.predict = predict
    try:
        x = rgb.clone().requires_grad_(True)
        value = call(loss, x, seed=3)
        (g_loss,) = torch.autograd.grad(value, x)
        # with the prediction and draws fixed, the residual is a constant r = w(ε̂ − ε):
        # dL/dx = J_E^T r, i.e. the gradient of <r, E(x)>
        rng = torch.Generator().manual_seed(3)
        z = prior.encode(rgb, generator=rng)
        t = torch.randint(20, 981, (1,), generator=rng)
        eps = torch.randn(z.shape, generator=rng).double()  # drawn in float32 as the loss does
        r = (1 - prior.alphas_cumprod[t].double()) * (frozen["p"].eps - eps)

        def linear(xx):
            return (r * prior.encode(xx, generator=torch.Generator().manual_seed(3))).sum()

        x2 = rgb.clone().requires_grad_(True)
        (g_lin,) = torch.autograd.grad(linear(x2), x2)
        torch.testing.assert_close(g_loss, g_lin, rtol=1e-6, atol=1e-12)
        fd_check_pixel(linear, rgb, h=1e-6, rtol=1e-5)
    finally:
        del prior.predict


@pytest.mark.parametrize("kind", ["cogvideox", "modelscope"])
def test_two_iterations_move_theta(kind):
    loss = build("sds", tiny_prior(kind))
    values, grads, theta = two_iterations_move_theta(loss)
    assert all(math.isfinite(v) for v in values)
    assert all(math.isfinite(g) and g != 0 for g in grads)
    assert theta != 0.4
