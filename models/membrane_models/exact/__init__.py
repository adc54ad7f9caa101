"""Exact reference solutions: one entry point for every problem.

``exact_solution(problem, rtol)`` returns an ``ExactSolution`` (see ``solution``):

- forced string and membrane: the sine-mode series with exact Duhamel integrals (``forced``),
  its modes chosen from the force's spectrum (``mode_selection``) so that the stated relative
  truncation error is at most ``rtol``;
- plucked string (kinked or smoothed): d'Alembert's closed form (``plucked``), exact to rounding.
  Its Fourier series, ``PluckedFourier``, is the independent cross-check;
- the Kirchhoff-Carrier string (``kirchhoff_carrier``): its Galerkin system, complete for the
  problem's initial modes, integrated to ``rtol`` (at least 1e-13).
"""

from __future__ import annotations

from collections.abc import Callable

from membrane_models.budget import MemoryBudgetExceeded
from membrane_models.exact.forced import ForcedModalSolution, forced_modal_solution
from membrane_models.exact.kirchhoff_carrier import KirchhoffReference
from membrane_models.exact.plucked import PluckedDAlembert, PluckedFourier
from membrane_models.exact.solution import (
    ExactSolution,
    FrameFunction,
    InvalidQuery,
    PointFrames,
)
from membrane_models.problems import (
    MembraneForced,
    Problem,
    StringForced,
    StringKirchhoff,
    StringPlucked,
)

__all__ = [
    "DEFAULT_RTOL",
    "EXACT_SOLVERS",
    "ExactSolution",
    "ForcedModalSolution",
    "FrameFunction",
    "InvalidQuery",
    "MemoryBudgetExceeded",
    "PluckedDAlembert",
    "PluckedFourier",
    "PointFrames",
    "exact_solution",
]

DEFAULT_RTOL = 1e-10


def exact_solution(
    problem: Problem, rtol: float = DEFAULT_RTOL, max_bytes: int | None = None
) -> ExactSolution:
    """The exact solution of ``problem``, series truncated at relative error ``rtol``.

    Args:
        problem: any registered problem (see ``problems.make_problem``).
        rtol: bound on the relative truncation error of series solutions (ignored by the
            closed forms, which are exact).
        max_bytes: most memory building the solution may take (None: the solvers' own fixed
            limits only); what it then holds is ``memory_bytes``.

    Raises:
        ValueError: rtol not a positive number, or a problem type without an exact solution.
        MemoryBudgetExceeded: (a ValueError) the solution needs more than ``max_bytes``.
    """
    solver = EXACT_SOLVERS.get(type(problem))
    if solver is None:
        raise ValueError(f"no exact solution for {type(problem).__name__}")
    return solver(problem, rtol, max_bytes)


def _plucked(problem: Problem, rtol: float, max_bytes: int | None) -> ExactSolution:
    assert isinstance(problem, StringPlucked)
    return PluckedDAlembert(problem)  # a closed form: exact to rounding, whatever rtol


def _forced(problem: Problem, rtol: float, max_bytes: int | None) -> ExactSolution:
    assert isinstance(problem, StringForced | MembraneForced)
    return forced_modal_solution(problem, rtol, max_bytes)


def _kirchhoff(problem: Problem, rtol: float, max_bytes: int | None) -> ExactSolution:
    assert isinstance(problem, StringKirchhoff)
    return KirchhoffReference(problem, rtol)


# The registry, problem class -> builder(problem, rtol, max_bytes): a new problem with an exact
# solution adds one entry here (as torchdiffeq's SOLVERS).
ExactSolver = Callable[[Problem, float, "int | None"], ExactSolution]
EXACT_SOLVERS: dict[type[Problem], ExactSolver] = {
    StringForced: _forced,
    MembraneForced: _forced,
    StringPlucked: _plucked,
    StringKirchhoff: _kirchhoff,
}
