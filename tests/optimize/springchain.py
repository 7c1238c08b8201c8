"""A real, tiny differentiable simulator for testing the optimisation loop: a damped
mass-spring chain in PyTorch (float64), behind the same interfaces as the MPM bridge.

A chain of ``n`` point masses hangs from a fixed anchor (particle 0) under gravity,
starts at rest length (so gravity stretches it) with a sideways initial velocity,
and swings. Spring ``i`` joins particles ``i`` and ``i+1`` with stiffness ``k`` [N/m]
and a dashpot ``c`` [N s/m] along the spring. Integration is semi-implicit Euler
with ``substeps`` per frame. ``grad_mode`` has the bridge's meaning:

- ``full``: gradients through every substep (frames recomputed in the backward pass
  with ``torch.utils.checkpoint``);
- ``window``: through the last ``window`` substeps before each supervised frame only
  (the state entering a window is detached);
- ``last_substep``: ``window`` with one substep.

Also a differentiable "camera": particles projected on the x-z plane drawn as dark
Gaussian blobs on white, so ``video_match`` can be tested without the splat renderer.
Run as a script it performs a fit into a directory (used by the SIGKILL resume test).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import torch
from torch.utils.checkpoint import checkpoint

TRUE = {"k": 40.0, "c": 0.3}
"""Parameters of the synthetic references."""


class LogThetaMap:
    """theta_i = log(value_i / ref_i), ref = geometric middle of the range."""

    def __init__(self, names, ranges):
        self.names = list(names)
        self.ranges = ranges
        self.ref = {n: math.sqrt(ranges[n][0] * ranges[n][1]) for n in self.names}

    def to_theta(self, values):
        return torch.tensor(
            [math.log(values[n] / self.ref[n]) for n in self.names], dtype=torch.float32
        )

    def from_theta(self, theta):
        return {n: self.ref[n] * torch.exp(theta[i]) for i, n in enumerate(self.names)}


RANGES = {"k": (1.0, 1000.0), "c": (1e-3, 1.0)}


class SpringChain:
    def __init__(
        self,
        n=5,
        num_frames=16,
        substeps=10,
        frame_dt=0.05,
        rest=0.1,
        mass=0.05,
        velocity=(0.6, 0.0, 0.0),
    ):
        self.num_particles = n
        self.num_frames = num_frames
        self.substeps = substeps
        self.dt = frame_dt / substeps
        self.rest = rest
        self.mass = mass
        self.velocity = torch.tensor(velocity, dtype=torch.float64)
        self.x0 = torch.zeros(n, 3, dtype=torch.float64)
        self.x0[:, 2] = -rest * torch.arange(n, dtype=torch.float64)
        self.gravity = torch.tensor([0.0, 0.0, -9.8], dtype=torch.float64)
        self.free = torch.ones(n, 1, dtype=torch.float64)
        self.free[0] = 0.0  # the anchor

    # one substep; k and c are scalars or [n] (spring i uses particle i+1's value)
    def _substep(self, x, v, k, c):
        ks = k if k.ndim == 0 else k[1:]
        cs = c if c.ndim == 0 else c[1:]
        d = x[1:] - x[:-1]  # [n-1, 3]
        length = d.norm(dim=-1, keepdim=True)
        u = d / length
        rel = ((v[1:] - v[:-1]) * u).sum(-1, keepdim=True)
        f_s = (ks * (length.squeeze(-1) - self.rest) + cs * rel.squeeze(-1))[:, None] * u
        force = torch.zeros_like(x)
        force = force.index_add(0, torch.arange(1, x.shape[0]), -f_s)
        force = force.index_add(0, torch.arange(0, x.shape[0] - 1), f_s)
        v = (v + self.dt * (force / self.mass + self.gravity)) * self.free
        x = x + self.dt * v
        return x, v

    def _frame(self, x, v, k, c):
        for _ in range(self.substeps):
            x, v = self._substep(x, v, k, c)
        return x, v

    def simulate(self, sim_params, initial_velocity, frames, grad_mode, window):
        k = sim_params["k"].double()
        c = sim_params["c"].double()
        vel = self.velocity if initial_velocity is None else initial_velocity.double()
        x = self.x0.clone()
        v = vel.expand(self.num_particles, 3) * self.free
        frames = sorted(int(f) for f in frames)
        wanted = set(frames)
        last = frames[-1]
        out = {0: x} if 0 in wanted else {}
        S = self.substeps
        w = S * last + 1 if grad_mode == "full" else (1 if grad_mode == "last_substep" else window)

        def in_window(g):
            return any(f * S - w <= g < f * S for f in frames)

        for f in range(1, last + 1):
            if grad_mode == "full":
                x, v = checkpoint(self._frame, x, v, k, c, use_reentrant=False)
            else:
                for s in range(S):
                    g = (f - 1) * S + s
                    if in_window(g):
                        if not in_window(g - 1):
                            x, v = x.detach(), v.detach()
                        x, v = self._substep(x, v, k, c)
                    else:
                        with torch.no_grad():
                            x, v = self._substep(x, v, k, c)
            if f in wanted:
                out[f] = x
        xs = torch.stack([out[f] for f in frames]).float()
        Fs = torch.eye(3).expand(len(frames), self.num_particles, 3, 3)
        return xs, Fs


def blob_camera(height=24, width=24, extent=0.7, sigma=0.03):
    """x-z projection of particles as dark Gaussian blobs on white -> [S,H,W,3]."""
    ys = torch.linspace(0.05, -extent, height)
    xs_ = torch.linspace(-extent / 2, extent / 2, width)
    gz, gx = torch.meshgrid(ys, xs_, indexing="ij")  # [H, W]

    def render(xs, Fs):
        px = xs[..., 0][:, :, None, None]  # [S, P, 1, 1]
        pz = xs[..., 2][:, :, None, None]
        ink = torch.exp(-((gx - px) ** 2 + (gz - pz) ** 2) / (2 * sigma**2)).sum(1)  # [S, H, W]
        gray = 1.0 - ink.clamp(max=1.0) * 0.9
        return gray[..., None].expand(*gray.shape, 3)

    return render


def make_problem(loss, start=None, names=("k", "c"), per_particle=(), chain=None, renderer=None):
    from motionphysics.optimize import ParamSpec, Problem

    chain = chain or SpringChain()
    start = start or {"k": TRUE["k"] * 5, "c": TRUE["c"] / 5}
    fixed = {n: TRUE[n] for n in ("k", "c") if n not in names}
    return Problem(
        theta_map=LogThetaMap(names, RANGES),
        initial={n: start[n] for n in names},
        fixed=fixed,
        to_sim=lambda phys: dict(phys),
        simulator=chain,
        loss=loss,
        renderer=renderer,
        specs={n: ParamSpec(n, "N/m" if n == "k" else "N s/m", *RANGES[n], "log") for n in names},
        per_particle=tuple(per_particle),
    )


def reference(chain, params=None):
    """[T, P, 3] positions of every frame for the given parameters (default TRUE)."""
    params = params or TRUE
    with torch.no_grad():
        xs, _ = chain.simulate(
            {k: torch.tensor(v) for k, v in params.items()},
            None,
            range(chain.num_frames),
            "last_substep",
            1,
        )
    return xs


def _main(out_dir: str, iterations: int) -> None:
    from motionphysics.config import OptimizeConfig
    from motionphysics.losses import get_loss
    from motionphysics.optimize import optimize

    resume = "--resume" in sys.argv
    torch.set_num_threads(1)
    chain = SpringChain(num_frames=8, substeps=12)
    loss = get_loss("trajectory_match")(reference(chain))
    cfg = OptimizeConfig(
        loss="trajectory_match", iterations=iterations, boost=3, lr=0.1, tolerance=0.0, seed=3
    )
    res = optimize(
        make_problem(loss, chain=chain), cfg, out_dir, resume=resume, fingerprint="chain"
    )
    torch.save({k: v for k, v in res.theta.items()}, Path(out_dir) / "final_theta.pt")


if __name__ == "__main__":
    _main(sys.argv[1], int(sys.argv[2]))
