"""Several objects optimised together (optimize.objects): each object's phrase of the
prompt, the per-object parameter lists, the stacked theta map, the gradient of a
trajectory loss with respect to each object's theta against central differences, the
per-object loss of a prior that observes states, and the one-parameter-at-a-time global
stage."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from motionphysics.assembly import assemble
from motionphysics.config import config_from_dict
from motionphysics.errors import UserInputError
from motionphysics.io.object_params import flat_params
from motionphysics.losses.base import Loss, LossContext, Prediction
from motionphysics.optimize.objects import (
    ObjectsThetaMap,
    PerObjectLoss,
    build_objects_problem,
    final_scene_material,
    object_indices,
    object_prompt,
    object_prompts,
    objects_optimised,
)


def _ball(name, x, v, E, **extra):
    return {
        "name": name,
        "source": "builtin:sphere",
        "scale": 0.12,
        "translate": [x, 0.0, 0.5],
        "max_particles": 40,
        "material": {"class": "elastic", "density": 500.0, "E": E, "nu": 0.3},
        "initial_velocity": [v, 0.0, 0.0],
        **extra,
    }


def _data(E_a=4.0e4, E_b=2.0e4, **optimize):
    return {
        "prompt": "The ball a bounces high and the ball b wobbles.",
        "objects": [_ball("a", -0.07, 2.0, E_a), _ball("b", 0.07, -2.0, E_b)],
        "sim": {
            "domain": [[-0.3, -0.15, 0.35], [0.3, 0.15, 0.65]],
            "grid": 12,
            "frames": 3,
            "frame_dt": 0.01,
            "substeps": 10,
            "gravity": [0, 0, 0],
        },
        "boundary_conditions": [],
        "optimize": optimize,
    }


@pytest.fixture(scope="module")
def two_balls():
    cfg = config_from_dict(_data(params={"a": ["E"], "b": ["E"]}))
    return assemble(cfg, needs_grad=True, estimate=False, reference_image=False)


# --- each object's phrase -----------------------------------------------------------------
@pytest.mark.parametrize(
    ("prompt", "name", "want"),
    [
        (
            "The rubber ball bounces high and the jelly cube wobbles",
            "ball",
            "The rubber ball bounces high",
        ),
        (
            "The rubber ball bounces high and the jelly cube wobbles",
            "cube",
            "the jelly cube wobbles",
        ),
        ("A steel axe falls, while the rubber ducks wobble.", "duck", "the rubber ducks wobble"),
        (
            "the soft_block squashes flat; the hard ball keeps its shape",
            "soft_block",
            "the soft_block squashes flat",
        ),
    ],
)
def test_object_phrase_is_the_clause_that_names_it(prompt, name, want):
    assert object_prompt(prompt, name, ("ball", "cube", "axe", "duck", "soft_block")) == want


def test_a_clause_naming_only_this_object_wins_and_an_unnamed_object_has_none():
    p = "The ball hits the cube, and then the cube wobbles"
    assert object_prompt(p, "cube", ("ball", "cube")) == "the cube wobbles"
    assert object_prompt(p, "ball", ("ball", "cube")) == "The ball hits the cube"
    assert object_prompt(p, "torus", ("ball", "torus")) is None


def test_object_prompts_take_the_config_key_first_and_refuse_an_unnamed_object():
    data = _data()
    data["objects"][1]["prompt"] = "a wobbly jelly ball"
    cfg = config_from_dict(data)
    assert object_prompts(cfg, ["a", "b"]) == {
        "a": "The ball a bounces high",
        "b": "a wobbly jelly ball",
    }
    data["objects"][1].pop("prompt")
    data["prompt"] = "The ball a bounces high."
    with pytest.raises(UserInputError, match=r"objects\[1\] \(b\).*objects\[1\]\.prompt") as err:
        object_prompts(config_from_dict(data), ["a", "b"])
    assert "\n" not in str(err.value)
    # an object whose parameters are not optimised needs no phrase (it is not observed)
    assert object_prompts(config_from_dict(data), ["a", "b"], {"a"}) == {
        "a": "The ball a bounces high"
    }


# --- which parameters ----------------------------------------------------------------------
def test_per_object_params_and_their_one_line_errors(two_balls):
    parts = two_balls
    assert objects_optimised(parts.cfg, parts.objects) == {"a": ["E"], "b": ["E"]}
    # a list applies to every object; an object a mapping leaves out is not optimised
    one = parts.cfg.model_copy(
        update={"optimize": parts.cfg.optimize.model_copy(update={"params": ["E", "nu"]})}
    )
    assert objects_optimised(one, parts.objects) == {"a": ["E", "nu"], "b": ["E", "nu"]}
    only = parts.cfg.model_copy(
        update={"optimize": parts.cfg.optimize.model_copy(update={"params": {"b": ["nu"]}})}
    )
    assert objects_optimised(only, parts.objects) == {"b": ["nu"]}
    bad = parts.cfg.model_copy(
        update={"optimize": parts.cfg.optimize.model_copy(update={"params": {"a": ["mu"]}})}
    )
    with pytest.raises(
        UserInputError, match=r"^optimize\.params\.a: mu not parameters of class elastic"
    ) as err:
        objects_optimised(bad, parts.objects)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("optimize", "match"),
    [
        (
            {"params": {"c": ["E"]}},
            r"optimize\.params: c not an object of this scene; expected names among a, b",
        ),
        ({"params": {}}, r"optimize\.params: empty mapping"),
        (
            {"per_particle": ["E"], "params": ["E"]},
            r"optimize\.per_particle: per-particle fields are for one object",
        ),
        ({"initial_velocity": True}, r"optimize\.initial_velocity: with several objects"),
    ],
)
def test_bad_objects_optimize_keys_are_one_line_errors(optimize, match):
    with pytest.raises(UserInputError, match=match) as err:
        config_from_dict(_data(**optimize))
    assert "\n" not in str(err.value)


def test_a_params_mapping_needs_objects():
    with pytest.raises(UserInputError, match="a mapping by object name needs objects") as err:
        config_from_dict({"optimize": {"params": {"object": ["E"]}}})
    assert "\n" not in str(err.value)
    # the single-object list form is unchanged
    assert config_from_dict({"optimize": {"params": ["E"]}}).optimize.params == ["E"]


def test_refining_several_objects_is_accepted_by_the_config():
    cfg = config_from_dict(_data(prior="motion", params={"a": ["E"]}))
    assert cfg.optimize.prior == "motion" and cfg.optimize.params == {"a": ["E"]}


# --- theta ---------------------------------------------------------------------------------
def test_theta_map_stacks_each_objects_parameterisation():
    tm = ObjectsThetaMap([("a", "elastic", ["E", "nu"]), ("b", "metal", ["tau_Y"])])
    assert tm.names == ["a.E", "a.nu", "b.tau_Y"]
    values = {"a.E": 3.0e5, "a.nu": 0.31, "b.tau_Y": 2.0e8}
    theta = tm.to_theta(values)
    assert theta.shape == (3,)
    back = tm.from_theta(theta)
    for k, v in values.items():
        assert float(back[k]) == pytest.approx(v, rel=1e-9)


def test_flat_params_names_each_objects_values():
    rec = {"a": {"density": 500.0, "E": 1.0}, "b": {"E": 2.0}}
    assert flat_params(rec) == {"a.density": 500.0, "a.E": 1.0, "b.E": 2.0}
    one = {"E": 1.0, "nu": {"mean": 0.3, "min": 0.2, "max": 0.4}}
    assert flat_params(one) == one


class _TrajectoryL2(Loss):
    """Sum of squared distances to a reference trajectory, weighted per particle."""

    needs_states = True

    def __init__(self, ref, w):
        self.ref, self.w = ref, w

    def __call__(self, pred, ctx):
        d = pred.xs.double() - self.ref[list(pred.frame_indices)]
        return (d * self.w[list(pred.frame_indices)]).sum() * 100.0


def test_gradient_of_each_objects_theta_matches_central_differences(two_balls):
    parts = two_balls
    ref_parts = parts.with_materials(
        [
            type(o.material)("elastic", 500.0, {"E": e, "nu": 0.3})
            for o, e in zip(parts.objects, (2.5e4, 3.5e4), strict=True)
        ]
    )
    xs, _, _, _ = ref_parts.simulate(3)
    rng = np.random.default_rng(1)
    w = torch.tensor(rng.normal(size=xs.shape))
    loss = _TrajectoryL2(torch.as_tensor(np.asarray(xs), dtype=torch.float64), w)
    problem = build_objects_problem(parts, loss, {"a": ["E"], "b": ["E"]})
    frames = (1, 2)
    ctx = LossContext(iteration=0, num_frames=3)

    def value(theta):
        return loss(problem.forward(theta, frames, "full", 1, {}), ctx)

    theta = problem.initial_theta()
    value(theta).backward()
    grads = {k: float(v.grad) for k, v in theta.items()}
    h = 3e-3  # ~1 % of E through the logit of the log range
    for name in ("a.E", "b.E"):
        vals = []
        for sgn in (1, -1):
            th = {k: v.detach().clone() for k, v in theta.items()}
            th[name] = th[name] + sgn * h
            with torch.no_grad():
                vals.append(float(value(th)))
        fd = (vals[0] - vals[1]) / (2 * h)
        assert abs(fd) > 0
        assert grads[name] == pytest.approx(fd, rel=0.05, abs=1e-3 * abs(fd)), (name, grads, fd)
    # each object's values are reported under its name, and the final material has them
    params, sim = problem.report(theta)
    assert list(params) == ["a", "b"] and params["a"]["E"] == pytest.approx(4.0e4, rel=1e-4)
    assert params["b"]["density"] == 500.0 and set(sim["b"]) >= {"E", "nu"}
    mat = final_scene_material(problem, parts, theta)
    assert [o.material.values["E"] for o in mat.objects] == pytest.approx([4.0e4, 2.0e4], rel=1e-4)


# --- the per-object loss ---------------------------------------------------------------------
class _MeanHeight(Loss):
    """A states loss: the mean height of the particles it is given, times a factor."""

    needs_states = True

    def __init__(self, factor):
        self.factor = factor
        self.seen = None
        self.state = {"calls": 0}

    def __call__(self, pred, ctx):
        self.seen = tuple(pred.xs.shape)
        self.state["calls"] += 1
        return pred.xs[..., 2].mean() * self.factor

    def components(self):
        return {"height": 1.0}

    def state_dict(self):
        return dict(self.state)

    def load_state_dict(self, state):
        self.state = dict(state)


def test_per_object_loss_gives_each_object_its_own_particles(two_balls):
    idx = object_indices(two_balls)
    assert [int(i.numel()) for i in idx] == [o.count for o in two_balls.objects]
    la, lb = _MeanHeight(1.0), _MeanHeight(10.0)
    loss = PerObjectLoss([("a", idx[0], la), ("b", idx[1], lb)])
    P = two_balls.num_particles
    xs = torch.zeros(2, P, 3, requires_grad=True)
    with torch.no_grad():
        xs[:, idx[1], 2] = 1.0  # object b is 1 m up
    pred = Prediction(frame_indices=(1, 2), xs=xs, Fs=torch.eye(3).expand(2, P, 3, 3))
    v = loss(pred, LossContext(iteration=0, num_frames=3))
    assert float(v.detach()) == pytest.approx(10.0)
    assert la.seen == (2, idx[0].numel(), 3) and lb.seen == (2, idx[1].numel(), 3)
    v.backward()
    g = xs.grad[..., 2]
    n_a, n_b = idx[0].numel(), idx[1].numel()
    assert torch.allclose(g[:, idx[0]], torch.full((2, n_a), 1.0 / (2 * n_a)))
    assert torch.allclose(g[:, idx[1]], torch.full((2, n_b), 10.0 / (2 * n_b)))
    assert loss.components() == {"a": 0.0, "a.height": 1.0, "b": 10.0, "b.height": 1.0}
    state = loss.state_dict()
    assert state == {"a": {"calls": 1}, "b": {"calls": 1}}
    loss.load_state_dict({"a": {"calls": 7}, "b": {"calls": 9}})
    assert la.state == {"calls": 7} and lb.state == {"calls": 9}


def test_each_object_sees_the_motion_prior_with_its_own_rest_state_and_phrase(two_balls):
    from motionphysics.optimize.objects import object_prior
    from motionphysics.optimize.refine import scene_context
    from motionphysics.priors import load_prior

    prior = load_prior("motion", None)
    idx = object_indices(two_balls)
    whole = scene_context(two_balls)
    prior.set_scene(whole)
    views = [
        object_prior(prior, phrase, scene_context(two_balls, i))
        for phrase, i in zip(("the ball a bounces high", "the ball b wobbles"), idx, strict=True)
    ]
    rest = torch.as_tensor(np.asarray(two_balls.sim_scene.particles), dtype=torch.float32)
    for view, i, phrase in zip(
        views, idx, ("the ball a bounces high", "the ball b wobbles"), strict=True
    ):
        assert torch.equal(view.scene.rest, rest[i])
        assert view.text.prompt == phrase
        assert view.net is prior.net  # the same network, not a copy
    assert prior.scene is whole and prior._text is None  # the shared prior is untouched


# --- the global stage, one parameter at a time ----------------------------------------------
def test_coordinate_search_finds_a_separable_minimum_a_hypercube_misses():
    from motionphysics.optimize.fit import _coordinate_search

    target = np.array([0.31, 0.77])
    scores, points = [], []

    def evaluate(u, rnd):
        points.append(np.asarray(u, dtype=np.float64))
        # a narrow valley along each axis (each object's parameter shapes its own motion)
        scores.append(float(np.sum(np.log1p(((u - target) / 0.03) ** 2))))

    lo, hi = np.full(2, 1e-4), np.full(2, 1 - 1e-4)
    evaluate(np.array([0.9, 0.1]), 0)
    _coordinate_search(evaluate, scores, points, 2, 9, 4, lo, hi, 3)
    best = points[int(np.argmin(scores))]
    assert len(points) <= 1 + 9 * 2 + 4 * 2
    assert np.all(np.abs(best - target) < 0.05), best


def test_an_interrupted_optimisation_of_two_objects_resumes_to_the_same_parameters(
    two_balls, tmp_path
):
    from motionphysics.optimize.loop import optimize

    parts = two_balls
    ref_parts = parts.with_materials(
        [type(o.material)("elastic", 500.0, {"E": 3.0e4, "nu": 0.3}) for o in parts.objects]
    )
    xs, _, _, _ = ref_parts.simulate(3)
    w = torch.ones(tuple(np.asarray(xs).shape), dtype=torch.float64)
    opt = parts.cfg.optimize.model_copy(update={"lr": 0.1, "warmup": 0, "boost": 1})

    def problem():
        loss = _TrajectoryL2(torch.as_tensor(np.asarray(xs), dtype=torch.float64), w)
        return build_objects_problem(parts, loss, {"a": ["E"], "b": ["E"]})

    whole = optimize(problem(), opt, tmp_path / "whole", iterations=3)

    class Stop(Exception):
        pass

    def stop_after_one(rec):
        if rec["iteration"] == 0:
            raise Stop

    with pytest.raises(Stop):
        optimize(problem(), opt, tmp_path / "cut", iterations=3, progress=stop_after_one)
    resumed = optimize(problem(), opt, tmp_path / "cut", iterations=3, resume=True)
    assert [r["iteration"] for r in resumed.history] == [0, 1, 2]
    for k in ("a.E", "b.E"):
        assert float(resumed.theta[k]) == float(whole.theta[k])
    assert resumed.params == whole.params and set(whole.params) == {"a", "b"}


def test_each_objects_motion_features_have_the_gradient_of_central_differences(two_balls):
    """The states prior's observation of each object (its particles, its rest state)
    through the simulation of both: d(sum_k w_k . z_k)/d theta against differences."""
    import copy

    from motionphysics.optimize.refine import scene_context
    from motionphysics.priors.motion import MotionDenoiser, MotionPrior, net_config
    from motionphysics.priors.motion_features import NUM_FEATURES

    parts = two_balls
    torch.manual_seed(0)
    from motionphysics.priors.motion_text import MotionText

    prior = MotionPrior(
        MotionDenoiser(**net_config("test")),
        mean=torch.zeros(NUM_FEATURES),
        std=torch.ones(NUM_FEATURES),
        text=MotionText.default().config(),
    )
    idx = object_indices(parts)
    views = []
    for i in idx:
        view = copy.copy(prior)
        view.set_scene(scene_context(parts, i))
        views.append(view)
    rng = np.random.default_rng(3)
    weights = [torch.tensor(rng.normal(size=(1, 16, NUM_FEATURES, 1, 1))) for _ in idx]

    class Features(Loss):
        needs_states = True

        def __call__(self, pred, ctx):
            total = 0.0
            for view, i, w in zip(views, idx, weights, strict=True):
                z = view.encode_states(pred.xs[:, i], pred.Fs[:, i], tuple(pred.frame_indices))
                total = total + (z.double() * w).sum()
            return total

    loss = Features()
    problem = build_objects_problem(parts, loss, {"a": ["E"], "b": ["E"]})
    ctx = LossContext(iteration=0, num_frames=3)

    def value(theta):
        return loss(problem.forward(theta, (1, 2), "full", 1, {}), ctx)

    theta = problem.initial_theta()
    value(theta).backward()
    h = 3e-3
    for name in ("a.E", "b.E"):
        vals = []
        for sgn in (1, -1):
            th = {k: v.detach().clone() for k, v in theta.items()}
            th[name] = th[name] + sgn * h
            with torch.no_grad():
                vals.append(float(value(th)))
        fd = (vals[0] - vals[1]) / (2 * h)
        got = float(theta[name].grad)
        assert abs(fd) > 1e-6
        assert got == pytest.approx(fd, rel=0.05, abs=1e-3 * abs(fd)), (name, got, fd)
