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
    "ExactSolution",
    "InvalidProblem",
    "MembraneForced",
    "Problem",
    "StringForced",
    "StringPlucked",
    "exact_solution",
    "make_problem",
]

# The exact solutions need scipy (the `server` extra); they load on first use so that importing
# the package (the `membrane` command does) works with the core dependencies alone.
_LAZY = {"ExactSolution": "membrane_models.exact", "exact_solution": "membrane_models.exact"}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'membrane_models' has no attribute {name!r}")
