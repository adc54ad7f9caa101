"""membrane_models: the problems, their exact solutions, and the networks trained on them.

Everything importable here works with the ``server`` extra alone (numpy, scipy); the training
and export modules need the ``train`` extra (torch, onnx) and are imported on demand.
"""

from membrane_models.problems import (
    PROBLEMS,
    InvalidProblem,
    MembraneForced,
    Problem,
    StringForced,
    StringPlucked,
    make_problem,
)

__all__ = [
    "PROBLEMS",
    "InvalidProblem",
    "MembraneForced",
    "Problem",
    "StringForced",
    "StringPlucked",
    "make_problem",
]
