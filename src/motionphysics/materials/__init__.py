"""Materials: the catalogue of classes and ranges, theta parameterisation, the sim map.

``catalog`` holds the paper's appendix table (the one place with the ranges);
``simmap`` owns the only map between physical and simulation values; ``theta`` the
unconstrained optimisation vector. See docs/CONTRACTS.md ("materials").
"""

from motionphysics.materials.catalog import (
    DENSITY,
    MATERIALS,
    Clamp,
    MaterialParams,
    normalise_class,
    param_names,
    validate,
)
from motionphysics.materials.simmap import SimContext, physical_to_sim, sim_to_physical

__all__ = [
    "DENSITY",
    "MATERIALS",
    "Clamp",
    "MaterialParams",
    "normalise_class",
    "param_names",
    "validate",
    "SimContext",
    "physical_to_sim",
    "sim_to_physical",
    "Parameterisation",
]


def __getattr__(name):
    # theta imports torch; keep `import motionphysics.materials` light.
    if name == "Parameterisation":
        from motionphysics.materials.theta import Parameterisation

        return Parameterisation
    raise AttributeError(name)
