"""``bench prior`` and ``bench iteration``: the cost of the refinement stage.

- ``bench prior --model M --random-weights [--size tiny|full] [--device D] [--json]``:
  the prior's part of one LMD iteration (:func:`motionphysics.optimize.prior_bench.run_prior_bench`:
  encode with grad, one guided prediction, backward to the frames; peak memory).
- ``bench iteration [--config FILE] [--model M] [--json]``: one whole LMD iteration of
  ``run`` (simulate -> render -> prior -> backward to theta) on the demo config (CPU),
  with the split of its time, reported as a ratio to a forward (no-grad) simulate+render
  of the same frames. The prior is a random-weights architecture at tiny size
  (:func:`~motionphysics.optimize.prior_bench.build_random_prior`), so the figure is the
  simulation and rendering cost plus a small prior; the prior's own cost at the
  published size is ``bench prior``.

The backward is split with tensor hooks: ``backward_prior`` ends when the gradient
reaches the rendered frames, ``backward_render`` when it reaches the particle states,
``backward_sim`` when it reaches theta. This module writes nothing; it prints.
"""

from __future__ import annotations

import json as _json
import time

__all__ = ["register_target", "run_iteration_bench"]


def run_iteration_bench(
    config: str | None = None,
    *,
    model: str = "cogvideox-2b",
    device: str = "cpu",
    boost: int = 8,
    resolution: int = 64,
    json: bool = False,
    out=print,
) -> dict:
    """Time one LMD iteration of the refinement on ``config`` (default: the demo)."""
    from importlib.resources import files

    import torch

    from motionphysics.assembly import assemble
    from motionphysics.losses.base import LossContext
    from motionphysics.losses.lmd import LmdLoss
    from motionphysics.optimize.boosting import frames_for_iteration
    from motionphysics.optimize.fit import build_problem
    from motionphysics.optimize.prior_bench import build_random_prior, check_model
    from motionphysics.optimize.refine import PerturbedRenderer
    from motionphysics.runconfig import load_run_config
    from motionphysics.runtime import check_device, set_threads

    check_model(model, "bench iteration")
    set_threads()
    path = config or str(files("motionphysics.commands") / "demo.yaml")
    cfg = load_run_config(path, {"device": device})
    dev = check_device(cfg.device)
    t0 = time.perf_counter()
    parts = assemble(cfg, dev, needs_grad=True, reference_image=False, config_origin=path)
    prior, n_params = build_random_prior(model, "tiny", dev, resolution=resolution)
    loss = LmdLoss(prior, prior.text.prompt, LmdLoss.Options())
    problem = build_problem(parts, loss)
    problem.renderer = PerturbedRenderer(problem.renderer, loss.render_perturbation, 0)
    setup_s = time.perf_counter() - t0
    frames = frames_for_iteration(0, int(cfg.sim.frames), boost)

    split = {"encode": 0.0, "predict": 0.0}

    def timed(name, fn):
        def wrapper(*a, **k):
            t = time.perf_counter()
            r = fn(*a, **k)
            split[name] += time.perf_counter() - t
            return r

        return wrapper

    prior.encode = timed("encode", prior.encode)
    prior.predict = timed("predict", prior.predict)

    def one_iteration() -> dict[str, float]:
        for k in split:
            split[k] = 0.0
        theta = problem.initial_theta()
        timings: dict[str, float] = {}
        t_start = time.perf_counter()
        pred = problem.forward(theta, frames, cfg.optimize.grad_mode, cfg.optimize.window, timings)
        marks: dict[str, float] = {}

        def mark(name):
            def hook(grad):  # records when the gradient arrives; returns None (grad unchanged)
                marks.setdefault(name, time.perf_counter())

            return hook

        pred.rgb.register_hook(mark("rgb"))
        pred.xs.register_hook(mark("xs"))
        t1 = time.perf_counter()
        value = loss(pred, LossContext(iteration=0, num_frames=int(cfg.sim.frames)))
        t2 = time.perf_counter()
        value.backward()
        t3 = time.perf_counter()
        grads = [theta[n].grad for n in problem.theta_map.names]
        if any(g is None or not torch.isfinite(g).all() for g in grads):
            raise RuntimeError("bench iteration: no finite gradient reached theta")
        t_rgb, t_xs = marks.get("rgb", t2), marks.get("xs", t3)
        return {
            "simulate_s": timings["simulate"],
            "render_s": timings["render"],
            "loss_s": t2 - t1,
            "encode_s": split["encode"],
            "predict_s": split["predict"],
            "backward_prior_s": t_rgb - t2,
            "backward_render_s": t_xs - t_rgb,
            "backward_sim_s": t3 - t_xs,
            "iteration_s": t3 - t_start,
        }

    one_iteration()  # warm-up: Warp kernels, allocator
    it = one_iteration()

    # the forward reference: no-grad simulate + render of the same frames
    t0 = time.perf_counter()
    with torch.no_grad():
        xs, Fs = problem.simulator.simulate(
            problem.sim_values(problem.initial_theta()), None, frames, "full", 1
        )
    t1 = time.perf_counter()
    parts.render(xs.detach(), Fs.detach())
    t2 = time.perf_counter()
    fwd = {"forward_simulate_s": t1 - t0, "forward_render_s": t2 - t1}
    fwd_total = fwd["forward_simulate_s"] + fwd["forward_render_s"]
    result = {
        "config": path,
        "device": str(dev),
        "particles": parts.num_particles,
        "splats": int(parts.sim_scene.splats.means.shape[0]),
        "camera": [int(cfg.camera.width), int(cfg.camera.height)],
        "frames_supervised": len(frames),
        "frames_simulated": int(max(frames)) + 1,
        "substeps": int(problem.simulator.substeps),
        "prior_model": f"{model} (tiny, random weights, {n_params} parameters)",
        "prior_frames": prior.num_frames,
        "prior_resolution": [prior.height, prior.width],
        "setup_s": round(setup_s, 3),
        **{k: round(v, 4) for k, v in it.items()},
        **{k: round(v, 4) for k, v in fwd.items()},
        "ratio_to_forward": round(it["iteration_s"] / fwd_total, 2),
    }
    if json:
        out(_json.dumps(result))
    else:
        for k, v in result.items():
            out(f"{k:>20}: {v}")
    return result


def _prior(args) -> int:
    from motionphysics.optimize.prior_bench import run_prior_bench

    run_prior_bench(args.model, args.random_weights, args.device, args.json, size=args.size)
    return 0


def _iteration(args) -> int:
    run_iteration_bench(
        args.config, model=args.model, device=args.device, resolution=args.resolution,
        json=args.json,
    )  # fmt: skip
    return 0


def register_target(sub) -> None:
    from motionphysics.optimize.prior_bench import MODELS_BENCHED, MODELS_REMOVED
    from motionphysics.registry import Choices

    models = Choices(MODELS_BENCHED, MODELS_REMOVED)  # a removed one: refused in one line

    p = sub.add_parser(
        "prior",
        help="time the prior's part of one LMD iteration (random weights)",
        description=(
            "Time the prior's part of one LMD iteration at the paper's setting (16 frames "
            "at 256x256: encode with gradients, one guided prediction, backward to the "
            "frames) and its peak memory, on an architecture built from the published "
            "configuration with random weights (nothing is downloaded). On CPU only "
            "--size tiny is feasible."
        ),
    )
    p.add_argument("--model", choices=models, required=True, help="prior architecture")
    p.add_argument(
        "--random-weights",
        action="store_true",
        help="build the published architecture with random weights (nothing is downloaded)",
    )
    p.add_argument(
        "--size",
        choices=["tiny", "full"],
        default="tiny",
        help="tiny: a few-layer model of the same structure; full: the published size (GPU)",
    )
    p.add_argument("--device", choices=["cpu", "cuda"], default="cpu", help="where to run")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_prior)

    p = sub.add_parser(
        "iteration",
        help="time one whole LMD iteration of run (simulate, render, prior, backward)",
        description=(
            "Time one whole LMD iteration of run on the demo config (simulate, render, "
            "prior, backward to the parameters) with the split of its time, as a ratio to "
            "a forward simulate and render of the same frames. The prior is a small "
            "random-weights architecture, so the figure is mostly simulation and rendering."
        ),
    )
    p.add_argument("--config", metavar="FILE", help="run config (default: the demo)")
    p.add_argument(
        "--model",
        choices=models,
        default="cogvideox-2b",
        help="prior architecture at tiny size with random weights (default cogvideox-2b)",
    )
    p.add_argument("--resolution", type=int, default=64, help="prior frame side (default 64)")
    p.add_argument("--device", choices=["cpu", "cuda"], default="cpu", help="where to run")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_iteration)
