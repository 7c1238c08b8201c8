"""The optimisation loop of MotionPhysics: frame boosting, Adam with a warm-up + cosine
schedule, checkpoint and resume, ``log.jsonl``.

Public API: :func:`optimize` runs a :class:`Problem` (parameters, simulator, renderer,
loss) and returns an :class:`OptimizeResult`. Nothing is imported from the simulator
or the renderer here; a problem receives them from its builder (:mod:`.fit`, through the assembly).
"""

from motionphysics.optimize.boosting import frames_for_iteration, subsequences
from motionphysics.optimize.loop import OptimizeResult, optimize
from motionphysics.optimize.problem import ParamSpec, Problem, Simulator, ThetaMap
from motionphysics.optimize.schedule import learning_rates, lr_factor

__all__ = [
    "OptimizeResult",
    "ParamSpec",
    "Problem",
    "Simulator",
    "ThetaMap",
    "frames_for_iteration",
    "learning_rates",
    "lr_factor",
    "optimize",
    "subsequences",
]
