"""A film is a live engine driven by the scene's own forcing.

The forced problems' force f = -h exp(-k rho^2) g_a(t) is one Gaussian load of radius
r = 1 / sqrt(k) at the force's centre, whose total force follows the time bump:

    membrane: F(t) = -h g_a(t) pi r^2,      string: F(t) = -h g_a(t) sqrt(pi) r,

negative: the study's force pushes the tissue along -axis, the way a probe presses. Stepping an
engine with these loads (first-order hold: the bump sampled at the step ends, linear between)
reproduces the exact film up to the hold's O(dt^2) error; the tests and docs/LIVE.md measure it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.engine import ModalEngine
from membrane_models.live.interface import Load
from membrane_models.problems import MembraneForced, StringForced, time_bump

__all__ = ["film_frames", "film_load"]

FloatArray = NDArray[np.float64]
ForcedProblem = StringForced | MembraneForced


def film_load(problem: ForcedProblem, t: float) -> Load:
    """The scene's forcing at time ``t`` as one live load."""
    radius = 1.0 / math.sqrt(problem.k)
    bump = float(time_bump(t, problem.a))
    if isinstance(problem, MembraneForced):
        return Load((problem.x0, problem.y0), -problem.h * bump * math.pi * radius**2, radius)
    return Load((problem.x0,), -problem.h * bump * math.sqrt(math.pi) * radius, radius)


def film_frames(engine: ModalEngine, problem: ForcedProblem, steps: int) -> Iterator[FloatArray]:
    """Frames at t = dt, 2 dt, ... of the engine driven from rest by the problem's forcing."""
    state = engine.start().state
    for index in range(1, steps + 1):
        result = engine.step(state, [film_load(problem, index * engine.dt)])
        state = result.state
        assert result.frame is not None
        yield result.frame
