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
- ``bench iteration --prior motion [--config FILE] [--repeats N] [--json]``: one LMD
  iteration of ``run --prior motion`` (the embedded motion prior, which observes the
  simulated states: nothing is rendered) with the shipped weights and the loss options
  ``run`` gives it, split into ``simulate`` (theta -> sim values and the rollout that
  records its tape for the backward), ``loss`` (of it ``features``: the prior's
  ``encode_states``, and ``predict``: its denoiser over every diffusion draw; the rest
  is the extractor's own training step), ``backward_prior`` (until the gradient reaches
  the simulated states) and ``backward_sim`` (from there to theta). The reference is a
  forward no-grad ``simulate`` of the same frames; iteration and forward alternate
  ``--repeats`` times after one warm-up each, and every figure is the median over the
  rounds (``ratio_to_forward``: median iteration / median forward;
  ``ratio_per_round``: each round's, whose median is ``ratio_median_of_rounds``).

``--grid``, ``--frames``, ``--particles``, ``--substeps`` override the config's
``sim.grid``, ``sim.frames``, ``scene.max_particles``, ``sim.substeps`` (either prior).

The backward is split with tensor hooks: ``backward_prior`` ends when the gradient
reaches the rendered frames, ``backward_render`` when it reaches the particle states,
``backward_sim`` when it reaches theta. This module writes nothing; it prints.
"""

from __future__ import annotations

import json as _json
import time

__all__ = ["register_target", "run_iteration_bench"]


def _timed(split: dict[str, float], name: str, fn):
    """``fn`` wrapped to add its wall time to ``split[name]`` (the prior's parts of a loss)."""

    def wrapper(*a, **k):
        t = time.perf_counter()
        r = fn(*a, **k)
        split[name] += time.perf_counter() - t
        return r

    return wrapper


def _overrides(device, grid, frames, particles, substeps) -> dict:
    return {
        "device": device,
        "sim.grid": grid,
        "sim.frames": frames,
        "scene.max_particles": particles,
        "sim.substeps": substeps,
    }


def _print(result: dict, json: bool, out) -> None:
    if json:
        out(_json.dumps(result))
    else:
        for k, v in result.items():
            out(f"{k:>26}: {v}")


def run_iteration_bench(
    config: str | None = None,
    *,
    prior: str = "pixel",
    model: str = "cogvideox-2b",
    device: str = "cpu",
    boost: int | None = None,
    resolution: int = 64,
    repeats: int = 3,
    grid: int | None = None,
    frames: int | None = None,
    particles: int | None = None,
    substeps: int | str | None = None,
    json: bool = False,
    out=print,
) -> dict:
    """Time one LMD iteration of the refinement on ``config`` (default: the demo).

    ``prior``: ``pixel`` (a tiny random-weights video prior of ``model``: simulate,
    render, prior, backward; one timed iteration) or ``motion`` (the embedded motion
    prior on the simulated states: :func:`run_motion_iteration_bench`)."""
    if prior == "motion":
        return run_motion_iteration_bench(
            config, device=device, boost=boost, repeats=repeats, grid=grid, frames=frames,
            particles=particles, substeps=substeps, json=json, out=out,
        )  # fmt: skip
    if prior != "pixel":
        raise ValueError(f"bench iteration: unknown prior {prior!r} (pixel or motion)")
    boost = 8 if boost is None else int(boost)
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
    cfg = load_run_config(path, _overrides(device, grid, frames, particles, substeps))
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

    prior.encode = _timed(split, "encode", prior.encode)
    prior.predict = _timed(split, "predict", prior.predict)

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
    _print(result, json, out)
    return result


def run_motion_iteration_bench(
    config: str | None = None,
    *,
    device: str = "cpu",
    boost: int | None = None,
    repeats: int = 3,
    grid: int | None = None,
    frames: int | None = None,
    particles: int | None = None,
    substeps: int | str | None = None,
    json: bool = False,
    out=print,
) -> dict:
    """One LMD iteration of ``run --prior motion`` on ``config`` (default: the demo),
    split, against a forward simulate of the same frames (see the module docstring)."""
    import statistics
    from importlib.resources import files

    import torch

    from motionphysics.assembly import assemble
    from motionphysics.losses.base import LossContext
    from motionphysics.optimize.boosting import frames_for_iteration
    from motionphysics.optimize.fit import build_problem
    from motionphysics.optimize.loop import iteration_threads
    from motionphysics.optimize.refine import (
        _boost_for_prior,
        build_losses,
        loss_build_context,
        scene_context,
    )
    from motionphysics.priors import load_prior
    from motionphysics.runconfig import load_run_config
    from motionphysics.runtime import check_device, set_threads

    if repeats < 1:
        raise ValueError("bench iteration: --repeats must be >= 1")
    set_threads()
    path = config or str(files("motionphysics.commands") / "demo.yaml")
    over = _overrides(device, grid, frames, particles, substeps)
    over["optimize.prior"] = "motion"
    if boost is not None:
        over["optimize.boost"] = int(boost)
    cfg = load_run_config(path, over)
    dev = check_device(cfg.device)
    t0 = time.perf_counter()
    parts = assemble(cfg, dev, needs_grad=True, reference_image=False, config_origin=path)
    prior = load_prior("motion", cfg.optimize.prior_path, device=dev)
    prior.set_prompt(cfg.prompt)
    prior.set_scene(scene_context(parts))
    bctx = loss_build_context(cfg, parts, prior, None, dev)
    loss = build_losses(cfg, bctx)  # what run builds: the prior's loss defaults included
    problem = build_problem(parts, loss)
    opt_cfg, _ = _boost_for_prior(cfg, prior)  # run's boost, capped for the prior's frames
    setup_s = time.perf_counter() - t0
    num_frames = int(cfg.sim.frames)
    sim_frames = frames_for_iteration(0, num_frames, int(opt_cfg.boost))

    split = {"features": 0.0, "predict": 0.0}

    prior.encode_states = _timed(split, "features", prior.encode_states)
    prior.predict = _timed(split, "predict", prior.predict)
    rng = torch.Generator().manual_seed(int(cfg.optimize.seed))

    def one_iteration(i: int) -> dict[str, float]:
        for k in split:
            split[k] = 0.0
        theta = problem.initial_theta()
        timings: dict[str, float] = {}
        marks: dict[str, float] = {}

        def hook(grad):  # records when the gradient reaches the states; grad unchanged
            marks.setdefault("xs", time.perf_counter())

        with iteration_threads(loss):  # as the optimisation loop runs an iteration
            t_start = time.perf_counter()
            pred = problem.forward(theta, sim_frames, opt_cfg.grad_mode, opt_cfg.window, timings)
            pred.xs.register_hook(hook)
            t1 = time.perf_counter()
            value = loss(pred, LossContext(iteration=i, num_frames=num_frames, rng=rng))
            t2 = time.perf_counter()
            value.backward()
            t3 = time.perf_counter()
        grads = [theta[n].grad for n in problem.theta_map.names]
        if any(g is None or not torch.isfinite(g).all() for g in grads):
            raise RuntimeError("bench iteration: no finite gradient reached theta")
        t_xs = marks.get("xs", t3)
        return {
            "simulate_s": timings["simulate"],
            "loss_s": t2 - t1,
            "features_s": split["features"],
            "predict_s": split["predict"],
            "backward_prior_s": t_xs - t2,
            "backward_sim_s": t3 - t_xs,
            "backward_s": t3 - t2,
            "iteration_s": t3 - t_start,
        }

    def forward() -> float:
        t = time.perf_counter()
        with torch.no_grad():
            problem.simulator.simulate(
                problem.sim_values(problem.initial_theta()), None, sim_frames, "full", 1
            )
        return time.perf_counter() - t

    one_iteration(0)  # warm-up: Warp kernels, allocator, the tape buffers
    forward()
    its, fwds = [], []
    for r in range(repeats):  # alternated, so both see the same load
        its.append(one_iteration(r + 1))
        fwds.append(forward())
    med = {k: statistics.median(x[k] for x in its) for k in its[0]}
    fwd = statistics.median(fwds)
    per_round = [x["iteration_s"] / f for x, f in zip(its, fwds, strict=True)]
    result = {
        "prior": "motion",
        "config": path,
        "device": str(dev),
        "particles": parts.num_particles,
        "grid": [int(n) for n in parts.sim_scene.grid_dims],
        "frames_supervised": len(sim_frames),
        "frames_simulated": int(max(sim_frames)) + 1,
        "substeps": int(problem.simulator.substeps),
        "boost": int(opt_cfg.boost),
        "loss": loss.label,
        "prior_frames": int(prior.num_frames),
        "repeats": repeats,
        "setup_s": round(setup_s, 3),
        **{k: round(v, 4) for k, v in med.items()},
        "forward_simulate_s": round(fwd, 4),
        "iteration_runs_s": [round(x["iteration_s"], 4) for x in its],
        "forward_simulate_runs_s": [round(f, 4) for f in fwds],
        "taped_rollout_over_forward": round(med["simulate_s"] / fwd, 3),
        "backward_over_forward": round(med["backward_s"] / fwd, 3),
        "ratio_to_forward": round(med["iteration_s"] / fwd, 3),
        "ratio_per_round": [round(x, 3) for x in per_round],
        "ratio_median_of_rounds": round(statistics.median(per_round), 3),
    }
    _print(result, json, out)
    return result


def _prior(args) -> int:
    from motionphysics.optimize.prior_bench import run_prior_bench

    run_prior_bench(args.model, args.random_weights, args.device, args.json, size=args.size)
    return 0


def _iteration(args) -> int:
    from motionphysics.errors import UserInputError

    substeps = args.substeps
    if substeps is not None and substeps != "auto":
        try:
            substeps = int(substeps)
        except ValueError:
            raise UserInputError(
                f"--substeps: expected a positive integer or 'auto', got {substeps!r}"
            ) from None
        if substeps < 1:
            raise UserInputError(f"--substeps: expected a positive integer, got {substeps}")
    for name in ("repeats", "grid", "frames", "particles", "boost"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise UserInputError(f"--{name}: expected a positive integer, got {v}")
    run_iteration_bench(
        args.config, prior=args.prior, model=args.model, device=args.device,
        resolution=args.resolution, boost=args.boost, repeats=args.repeats, grid=args.grid,
        frames=args.frames, particles=args.particles, substeps=substeps, json=args.json,
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
            "random-weights architecture, so the figure is mostly simulation and rendering. "
            "With --prior motion: the embedded motion prior with its shipped weights, which "
            "observes the simulated states (nothing is rendered); the split is simulate "
            "(the rollout recording its tape), loss (features, predict), backward through "
            "the prior and through the simulation, against a forward simulate of the same "
            "frames, iteration and forward alternated --repeats times (medians)."
        ),
    )
    p.add_argument("--config", metavar="FILE", help="run config (default: the demo)")
    p.add_argument(
        "--prior",
        choices=["pixel", "motion"],
        default="pixel",
        help="pixel: a tiny random-weights video prior (render in the loop); motion: the "
        "embedded motion prior on the simulated states (default pixel)",
    )
    p.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="--prior motion: timed iterations and forwards, alternated (default 3)",
    )
    p.add_argument(
        "--boost",
        type=int,
        default=None,
        help="frame boosting M (default: 8 for pixel; the config's, capped for the prior, "
        "for motion)",
    )
    p.add_argument("--grid", type=int, default=None, help="override sim.grid")
    p.add_argument("--frames", type=int, default=None, help="override sim.frames")
    p.add_argument("--particles", type=int, default=None, help="override scene.max_particles")
    p.add_argument("--substeps", default=None, help="override sim.substeps (integer or 'auto')")
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
