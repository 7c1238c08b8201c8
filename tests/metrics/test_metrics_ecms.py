"""ECMS on flows and videos with a known optical flow; DIS against the known flow."""

from __future__ import annotations

import math

import numpy as np
import pytest
from metrics_synth import translating_video

from motionphysics.errors import UserInputError
from motionphysics.metrics.ecms import ECMSConfig, ecms_from_flows, ecms_terms, ecms_video
from motionphysics.metrics.flow import compute_flows


def _uniform(vecs, h=20, w=24):
    """Flows [L, h, w, 2] equal to vecs[l] everywhere."""
    v = np.asarray(vecs, dtype=np.float64)
    return np.broadcast_to(v[:, None, None, :], (len(v), h, w, 2)).copy()


def test_uniform_translation_has_zero_temporal_and_laplacian_terms():
    L, v = 9, np.array([1.5, -2.0])
    out = ecms_from_flows(_uniform([v] * L))
    t = out["terms"]
    assert t["temporal"] == 0.0 and t["spatial"] == 0.0
    assert math.isclose(t["motion"], L * 2.5, rel_tol=1e-12)  # |v| = 2.5 px per flow
    assert math.isclose(out["ecms"], 1.0 / (L * 2.5 + 1e-3), rel_tol=1e-12)


def test_constant_acceleration_temporal_term_closed_form():
    # positions s_l = a l^2 / 2 -> F_{l,l+1} = a (l + 1/2), F_l - F_{l-1} = a for every l >= 1
    L, a = 7, np.array([0.3, 0.4])
    flows = _uniform([a * (l + 0.5) for l in range(L)])
    t = ecms_terms(flows)
    assert math.isclose(t["temporal"], (L - 1) * 0.25, rel_tol=1e-12)  # |a|^2 = 0.25
    assert math.isclose(t["motion"], 0.5 * sum(l + 0.5 for l in range(L)), rel_tol=1e-12)
    assert t["spatial"] == 0.0
    mean = ecms_terms(flows, ECMSConfig(frame_reduction="mean"))
    assert math.isclose(mean["temporal"], 0.25, rel_tol=1e-12)
    assert math.isclose(mean["motion"], t["motion"] / L, rel_tol=1e-12)


def test_laplacian_term_of_a_quadratic_flow():
    # u = c x^2, v = d y^2: lap u = 2c, lap v = 2d exactly (5-point stencil, unit spacing)
    h, w, c, d = 12, 15, 0.01, -0.02
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    f = np.stack([c * xx**2, d * yy**2], -1)[None]
    t = ecms_terms(f)
    assert math.isclose(t["spatial"], (2 * c) ** 2 + (2 * d) ** 2, rel_tol=1e-9)
    s = ecms_terms(f, ECMSConfig(pixel_reduction="sum"))
    assert math.isclose(
        s["spatial"], ((2 * c) ** 2 + (2 * d) ** 2) * (h - 2) * (w - 2), rel_tol=1e-9
    )


def test_bracketing_and_still_video_is_finite():
    still = _uniform([[0.0, 0.0]] * 4)
    out = ecms_from_flows(still, ECMSConfig(eps=1e-3))
    assert out["ecms"] == pytest.approx(1e3) and math.isfinite(out["ecms"])
    terms = {"motion": 2.0, "temporal": 0.5, "spatial": 0.25}
    from motionphysics.metrics.ecms import ecms_from_terms

    assert ecms_from_terms(terms, ECMSConfig(eps=0.01)) == pytest.approx(1 / 2.01 + 0.75)
    assert ecms_from_terms(
        terms, ECMSConfig(bracketing="reciprocal_sum", eps=0.01)
    ) == pytest.approx(1 / 2.76)
    with pytest.raises(UserInputError, match="ecms.bracketing"):
        ecms_terms(still, ECMSConfig(bracketing="nope"))


# DIS on a smooth texture translated by sub-pixel amounts: away from the border (where
# the texture enters the frame) DIS-MEDIUM recovers the flow with a mean end-point error
# of 0.01-0.10 px (measured, uint8 frames); 0.15 px mean / 0.25 px 95th percentile is
# the stated tolerance.
DIS_MEAN_TOL = 0.15
DIS_P95_TOL = 0.25


@pytest.mark.parametrize("v", [(1.0, 0.0), (2.3, -1.4), (-0.6, 0.8)])
def test_dis_agrees_with_known_flow(v):
    T = 4
    shifts = np.array([[v[0] * l, v[1] * l] for l in range(T)])
    frames = translating_video(shifts)
    flows = compute_flows(frames, "dis")
    assert flows.shape == (T - 1, 64, 80, 2) and flows.dtype == np.float32
    inner = flows[:, 8:-8, 8:-8]
    err = np.linalg.norm(inner - np.asarray(v, dtype=np.float32), axis=-1)
    assert err.mean() < DIS_MEAN_TOL and np.percentile(err, 95) < DIS_P95_TOL


def test_farneback_recovers_a_translation():
    shifts = np.array([[1.5 * l, 0.5 * l] for l in range(3)])
    flows = compute_flows(translating_video(shifts), "farneback")
    err = np.linalg.norm(flows[:, 10:-10, 10:-10] - [1.5, 0.5], axis=-1)
    assert np.median(err) < 0.2


def test_ecms_video_translation_and_acceleration_through_dis():
    T = 6
    cfg = ECMSConfig(flow_height=None)
    lin = translating_video(np.array([[1.2 * l, 0.0] for l in range(T)]))
    out = ecms_video(lin, cfg)
    assert out["flows"] == T - 1 and out["flow_size"] == [64, 80]
    assert out["terms"]["motion"] == pytest.approx((T - 1) * 1.2, rel=0.05)
    assert out["terms"]["temporal"] < 0.02  # exactly 0 for the true flow
    a = 0.4
    acc = translating_video(np.array([[0.5 * a * l * l, 0.0] for l in range(T)]))
    t = ecms_video(acc, cfg)["terms"]
    assert t["temporal"] == pytest.approx((T - 2) * a * a, rel=0.25)
    still = ecms_video(np.repeat(lin[:1], 4, 0), cfg)
    assert still["terms"]["motion"] < 1e-3 and math.isfinite(still["ecms"]) and still["ecms"] > 100


def test_raft_without_torchvision_is_one_line_error():
    pytest.importorskip("cv2")
    try:
        import torchvision  # noqa: F401

        pytest.skip("torchvision is installed here; the failure path is not reachable")
    except ImportError:
        pass
    frames = translating_video(np.zeros((2, 2)))
    with pytest.raises(UserInputError, match="torchvision") as err:
        compute_flows(frames, "raft", raft_weights="/nonexistent.pth")
    assert "\n" not in str(err.value)
