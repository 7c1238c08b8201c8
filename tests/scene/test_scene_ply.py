"""INRIA 3DGS ply: bit-exact round trips, the reference layout, the real donut, bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from motionphysics.errors import UserInputError
from motionphysics.scene import load_scene, read_ply, write_ply
from motionphysics.scene.gaussians import SH_C0, GaussianScene
from motionphysics.scene.ply import ply_kind

DONUT = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "donut.ply"

REFERENCE_ORDER = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
]


def random_scene(n: int, degree: int, seed: int = 0) -> GaussianScene:
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return GaussianScene(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.randn(n, 3, generator=g) - 4,
        quats=torch.randn(n, 4, generator=g) * 3,  # deliberately unnormalised
        logit_opacities=torch.randn(n, generator=g) * 2,
        sh=torch.randn(n, k, 3, generator=g),
    )


def bits(t: torch.Tensor) -> np.ndarray:
    return t.numpy().view(np.uint32)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_bit_exact(tmp_path, degree):
    scene = random_scene(257, degree)
    # Values whose float32 bit patterns are easy to mangle: subnormal, -0.0, huge.
    scene.means[0] = torch.tensor([1e-40, -0.0, 3.0e38])
    path = write_ply(scene, tmp_path / "s.ply")
    back = read_ply(path)
    assert back.sh_degree == degree
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
        np.testing.assert_array_equal(
            bits(getattr(back, name)), bits(getattr(scene, name)), err_msg=name
        )


def test_written_file_uses_the_reference_layout(tmp_path):
    scene = random_scene(5, 3)
    path = write_ply(scene, tmp_path / "s.ply")
    ply = PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"]
    assert ply.byte_order == "<" and not ply.text
    names = [p.name for p in ply["vertex"].properties]
    rest = [f"f_rest_{i}" for i in range(45)]
    assert names == REFERENCE_ORDER[:9] + rest + REFERENCE_ORDER[9:]
    assert all(p.val_dtype in ("f4", "float32") for p in ply["vertex"].properties)
    for n in ("nx", "ny", "nz"):
        assert np.all(ply["vertex"][n] == 0)
    header = path.read_bytes().split(b"end_header")[0]
    assert b"format binary_little_endian 1.0" in header
    assert b"property float f_rest_44" in header


def test_reads_a_hand_written_reference_file(tmp_path):
    """A file written from the spec with numpy/plyfile: check values after activation."""
    n, degree = 3, 1
    k = 4
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    dc = rng.normal(size=(n, 3)).astype(np.float32)
    rest = rng.normal(size=(n, 3 * (k - 1))).astype(np.float32)  # channel-major
    opacity_logit = np.array([0.0, 2.0, -3.0], np.float32)
    log_scale = np.log(np.array([[0.1, 0.2, 0.3], [1.0, 1.0, 1.0], [0.01, 0.5, 2.0]], np.float32))
    rot = np.array([[2.0, 0, 0, 0], [0, 0, 0, 5.0], [1.0, 1.0, 0, 0]], np.float32)  # w first
    props = (
        [("x", xyz[:, 0]), ("y", xyz[:, 1]), ("z", xyz[:, 2])]
        + [(f"f_dc_{i}", dc[:, i]) for i in range(3)]
        + [(f"f_rest_{i}", rest[:, i]) for i in range(9)]
        + [("opacity", opacity_logit)]
        + [(f"scale_{i}", log_scale[:, i]) for i in range(3)]
        + [(f"rot_{i}", rot[:, i]) for i in range(4)]
    )
    arr = np.empty(n, dtype=[(name, "<f4") for name, _ in props])
    for name, col in props:
        arr[name] = col
    path = tmp_path / "ref.ply"
    PlyData([PlyElement.describe(arr, "vertex")], byte_order="<").write(str(path))

    s = read_ply(path)
    assert s.sh_degree == degree and s.num == n
    np.testing.assert_array_equal(s.means.numpy(), xyz)
    # Activation: sigmoid(0)=0.5, sigmoid(2), sigmoid(-3); float32 math, ~1e-7 relative.
    np.testing.assert_allclose(s.opacities.numpy(), 1 / (1 + np.exp(-opacity_logit)), rtol=1e-6)
    np.testing.assert_allclose(s.scales.numpy(), np.exp(log_scale), rtol=1e-6)
    # rot (2,0,0,0) -> identity; (0,0,0,5) -> 180 deg about z; (1,1,0,0) -> 90 deg about x.
    r = s.rotation_matrices().numpy()
    np.testing.assert_allclose(r[0], np.eye(3), atol=1e-6)
    np.testing.assert_allclose(r[1], np.diag([-1.0, -1.0, 1.0]), atol=1e-6)
    np.testing.assert_allclose(r[2], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-6)
    # f_rest channel-major: f_rest_{c*3 + j} is coefficient j+1 of channel c.
    for c in range(3):
        for j in range(3):
            np.testing.assert_array_equal(s.sh[:, 1 + j, c].numpy(), rest[:, c * 3 + j])
    np.testing.assert_allclose(s.base_colors().numpy(), np.clip(0.5 + SH_C0 * dc, 0, 1), rtol=1e-6)
    # Covariance of Gaussian 2: R diag(s^2) R^T, brute force in float64.
    rr = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)
    want = rr @ np.diag(np.exp(2 * log_scale[2].astype(np.float64))) @ rr.T
    # float32 rotation entries carry ~1e-7 error, times the largest variance (4): atol 1e-6.
    np.testing.assert_allclose(s.covariances()[2].double().numpy(), want, rtol=1e-5, atol=1e-6)
    assert ply_kind(path) == "gaussians"


@pytest.mark.skipif(not DONUT.is_file(), reason=f"real capture not present at {DONUT}")
def test_reads_the_real_donut(tmp_path):
    s = load_scene(str(DONUT))
    assert s.num == 45624 and s.sh_degree == 0
    raw = PlyData.read(str(DONUT))["vertex"]
    np.testing.assert_array_equal(s.means[:, 1].numpy(), raw["y"])
    np.testing.assert_array_equal(s.quats[:, 3].numpy(), raw["rot_3"])
    np.testing.assert_array_equal(s.logit_opacities.numpy(), raw["opacity"])
    assert torch.isfinite(s.covariances()).all()
    # A real capture: a compact object (well under 1 m across) with mostly small splats.
    ext = (s.means.max(0).values - s.means.min(0).values).max()
    assert 0.05 < float(ext) < 1.0
    assert float(s.scales.median()) < 0.01 * float(ext) * 10
    back = read_ply(write_ply(s, tmp_path / "donut_copy.ply"))
    for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
        np.testing.assert_array_equal(
            bits(getattr(back, name)), bits(getattr(s, name)), err_msg=name
        )


# ---- bad files --------------------------------------------------------------------------


def _write_vertex(path, names, n=2, values=None):
    arr = np.zeros(n, dtype=[(name, "<f4") for name in names])
    if values:
        for k, v in values.items():
            arr[k] = v
    PlyData([PlyElement.describe(arr, "vertex")], byte_order="<").write(str(path))
    return path


FULL = [
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
]


def _one_line(err) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_missing_property_is_a_user_error(tmp_path):
    p = _write_vertex(tmp_path / "a.ply", [n for n in FULL if n != "rot_3"], values={"rot_0": 1})
    with pytest.raises(UserInputError) as e:
        load_scene(str(p))
    assert "rot_3" in _one_line(e) and "a.ply" in str(e.value)


def test_bad_rest_count_is_a_user_error(tmp_path):
    p = _write_vertex(
        tmp_path / "b.ply", FULL + [f"f_rest_{i}" for i in range(5)], values={"rot_0": 1}
    )
    with pytest.raises(UserInputError) as e:
        read_ply(p)
    assert "f_rest" in _one_line(e) and "5" in str(e.value)


def test_nan_is_a_user_error(tmp_path):
    p = _write_vertex(tmp_path / "c.ply", FULL, values={"rot_0": 1, "scale_1": [0.0, np.nan]})
    with pytest.raises(UserInputError) as e:
        read_ply(p)
    assert "scale" in _one_line(e) and "NaN" in str(e.value) and "index 1" in str(e.value)


def test_inf_and_zero_quaternion_are_user_errors(tmp_path):
    p = _write_vertex(tmp_path / "d.ply", FULL, values={"rot_0": 1, "x": [np.inf, 0.0]})
    with pytest.raises(UserInputError, match="x/y/z"):
        read_ply(p)
    p = _write_vertex(tmp_path / "e.ply", FULL, values={"rot_0": [1.0, 0.0]})
    with pytest.raises(UserInputError, match="rot"):
        read_ply(p)


def test_garbage_and_point_cloud_are_user_errors(tmp_path):
    g = tmp_path / "g.ply"
    g.write_bytes(b"this is not a ply file at all\n")
    with pytest.raises(UserInputError) as e:
        load_scene(str(g))
    _one_line(e)
    pc = _write_vertex(tmp_path / "pc.ply", ["x", "y", "z"])
    with pytest.raises(UserInputError, match="f_dc_0"):
        load_scene(str(pc))
    with pytest.raises(UserInputError, match="not found"):
        read_ply(tmp_path / "nope.ply")


def test_validate_names_origin_and_field():
    s = random_scene(4, 0)
    s.sh[2, 0, 1] = float("nan")
    with pytest.raises(UserInputError) as e:
        s.validate("my.ply")
    assert "my.ply" in str(e.value) and "'sh'" in str(e.value) and "index 2" in str(e.value)
    s = random_scene(4, 0)
    s.quats = s.quats[:, :3]
    with pytest.raises(UserInputError, match="quats"):
        s.validate("x")


def test_round_trip_any_finite_float32(tmp_path):
    """Property: every finite float32 bit pattern survives write/read unchanged."""
    from hypothesis import given, settings
    from hypothesis import strategies as st
    from hypothesis.extra.numpy import arrays

    finite = st.floats(width=32, allow_nan=False, allow_infinity=False)

    @settings(max_examples=15, deadline=None)
    @given(
        data=arrays(np.float32, (3, 3 + 3 + 4 + 1 + 48), elements=finite), degree=st.integers(0, 3)
    )
    def check(data, degree):
        k = (degree + 1) ** 2
        quats = data[:, 6:10].copy()
        # Quaternions of norm <= 1e-12 are degenerate (no rotation can be recovered from
        # them in float32) and rejected by validation; give those rows a valid w.
        degenerate = np.linalg.norm(quats.astype(np.float64), axis=1) <= 1e-12
        quats[:, 0] = np.where(degenerate, np.float32(1.0), quats[:, 0])
        scene = GaussianScene(
            means=torch.from_numpy(data[:, :3].copy()),
            log_scales=torch.from_numpy(data[:, 3:6].copy()),
            quats=torch.from_numpy(quats),
            logit_opacities=torch.from_numpy(data[:, 10].copy()),
            sh=torch.from_numpy(data[:, 11 : 11 + 3 * k].reshape(3, k, 3).copy()),
        )
        back = read_ply(write_ply(scene, tmp_path / "h.ply"))
        for name in ("means", "log_scales", "quats", "logit_opacities", "sh"):
            np.testing.assert_array_equal(bits(getattr(back, name)), bits(getattr(scene, name)))

    check()
