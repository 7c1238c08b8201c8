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
)
from motionphysics.init.llm import LLMError, LLMOptions

__all__ = [
    "BACKENDS",
    "EstimateOptions",
    "MaterialEstimate",
    "estimate",
    "estimate_many",
    "LLMError",
    "LLMOptions",
]
