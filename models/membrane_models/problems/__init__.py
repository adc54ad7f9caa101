"""The problems: wave equations on unit domains, as typed, validated objects.

Each problem is a frozen dataclass holding its physical parameters with the reference study's
defaults (``base``, ``forcing``, ``string``, ``membrane``). ``make_problem(name, overrides)``
builds one from its registry name and ``NAME=VALUE`` overrides (``registry``); invalid values
raise ``InvalidProblem`` (a ``ValueError``) with a message that names the parameter.

Conventions: nondimensional, spatial domain [0, 1] (the unit interval or the unit square), time
domain [0, t_end], fixed (zero) displacement on the whole boundary.
"""

from membrane_models.problems.base import InvalidProblem, Problem
from membrane_models.problems.forcing import ForcedProblem, time_bump
from membrane_models.problems.membrane import MembraneForced
from membrane_models.problems.registry import PARAMETER_HELP, PROBLEMS, make_problem
from membrane_models.problems.string import StringForced, StringKirchhoff, StringPlucked

__all__ = [
    "PARAMETER_HELP",
    "PROBLEMS",
    "ForcedProblem",
    "InvalidProblem",
    "MembraneForced",
    "Problem",
    "StringForced",
    "StringKirchhoff",
    "StringPlucked",
    "make_problem",
    "time_bump",
]
