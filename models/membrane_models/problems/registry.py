"""The problems by name: what scene files, ``membrane exact`` and the manifests refer to."""

from __future__ import annotations

from membrane_models.problems.base import InvalidProblem, Problem
from membrane_models.problems.membrane import MembraneForced
from membrane_models.problems.string import StringForced, StringKirchhoff, StringPlucked

__all__ = ["PARAMETER_HELP", "PROBLEMS", "make_problem"]


# What each parameter means, for `membrane exact --help` and docs/SCENES.md (one line each).
PARAMETER_HELP: dict[str, str] = {
    "c": "wave speed",
    "t_end": "end of the time domain",
    "h": "force amplitude (the force is -h exp(-k r^2) g_a(t))",
    "a": "time bump exponent (>= 1; the force peaks at t = 0.5 and ends at t = 1)",
    "k": "force concentration: the Gaussian's exp(-k r^2)",
    "x0": "force centre on x (forced) or the pluck's apex (plucked), in (0, 1)",
    "y0": "force centre on y, in (0, 1)",
    "height": "pluck height",
    "smoothing": "pluck smoothing: Gaussian standard deviation (0: a sharp kink)",
    "stretch": "Kirchhoff-Carrier stretch coefficient: the tension is c^2 + stretch int u_x^2 dx",
}

# Registry: name -> (class, default overrides). The smoothed pluck is a named variant.
PROBLEMS: dict[str, tuple[type[Problem], dict[str, str]]] = {
    StringForced.name: (StringForced, {}),
    StringPlucked.name: (StringPlucked, {}),
    "string-plucked-smooth": (StringPlucked, {"smoothing": "0.02"}),
    MembraneForced.name: (MembraneForced, {}),
    StringKirchhoff.name: (StringKirchhoff, {}),
}


def make_problem(name: str, overrides: dict[str, str] | None = None) -> Problem:
    """Build a registered problem with its defaults, then apply ``overrides``."""
    try:
        cls, defaults = PROBLEMS[name]
    except KeyError:
        raise InvalidProblem(
            f"unknown problem {name!r}; known: {', '.join(sorted(PROBLEMS))}"
        ) from None
    default = cls()  # type: ignore[call-arg]  # every registered class defaults all its fields
    return default.with_overrides({**defaults, **(overrides or {})})
