"""Material initialisation from a prompt: the kb, llm, median and naive backends.

``estimate(prompt, image=None, backend='kb', options=None) -> MaterialEstimate``;
see ``motionphysics.init.estimate`` and docs/CONTRACTS.md ("init"). Heavy imports
(sentence-transformers, openai) happen inside the backends, on first use.
"""

from motionphysics.init.estimate import (
    BACKENDS,
    EstimateOptions,
    MaterialEstimate,
    estimate,
    estimate_many,
    estimate_objects,
)
from motionphysics.init.llm import LLMError, LLMOptions
from motionphysics.registry import Registry

INIT_BACKENDS: Registry = Registry(
    "init backend",
    "--init",
    # Each name resolves to the entry point that runs it (``estimate(prompt, image,
    # backend=name)``); the names drive the CLI choices of run/init and the checks.
    {name: "motionphysics.init.estimate:estimate" for name in BACKENDS},
)

__all__ = [
    "BACKENDS",
    "INIT_BACKENDS",
    "EstimateOptions",
    "MaterialEstimate",
    "estimate",
    "estimate_many",
    "estimate_objects",
    "LLMError",
    "LLMOptions",
]
