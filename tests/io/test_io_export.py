"""Per-frame splat export: the written INRIA ply reads back as the deformed splats."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch

from motionphysics.io.export import export_splats, frame_file_name
from motionphysics.scene.gaussians import GaussianScene
from motionphysics.scene.ply import read_ply


def _scene(n=6, degree=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return GaussianScene(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.log(torch.rand(n, 3, generator=g) * 0.05 + 0.01),
        quats=torch.randn(n, 4, generator=g),
        logit_opacities=torch.randn(n, generator=g),
        sh=torch.randn(n, k, 3, generator=g),
    )


def test_export_matches_deformation(tmp_path):
    splats = _scene()
    P = 3
    parent = torch.tensor([0, 0, 1, 1, 2, 2])
    offset = torch.randn(6, 3, generator=torch.Generator().manual_seed(1)) * 0.01
    x = np.random.default_rng(0).normal(size=(2, P, 3)).astype(np.float32)
    c, s = math.cos(0.7), math.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    F1 = R @ np.diag([1.3, 0.8, 1.0])
    Fs = np.stack([np.tile(np.eye(3), (P, 1, 1)), np.tile(F1, (P, 1, 1))]).astype(np.float32)
    sim_scene = SimpleNamespace(splats=splats, splat_parent=parent, splat_offset=offset)
    paths = export_splats(sim_scene, x, Fs, tmp_path / "splats")
    assert [p.name for p in paths] == [frame_file_name(0), frame_file_name(1)]

    back0 = read_ply(paths[0])
    torch.testing.assert_close(back0.covariances(), splats.covariances(), rtol=1e-4, atol=1e-7)
    back1 = read_ply(paths[1])
    Ft = torch.as_tensor(F1, dtype=torch.float32)
    want_cov = Ft @ splats.covariances() @ Ft.T
    torch.testing.assert_close(back1.covariances(), want_cov, rtol=1e-4, atol=1e-7)
    want_means = torch.as_tensor(x[1])[parent] + offset @ Ft.T
    torch.testing.assert_close(back1.means, want_means, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(back1.sh, splats.sh)
    torch.testing.assert_close(back1.logit_opacities, splats.logit_opacities)
