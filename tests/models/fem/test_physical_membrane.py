"""The study's dimensionless membrane rebuilt as a physical one: FEM modes against the exact film.

``membrane-forced`` is z_tt = c^2 (z_xx + z_yy) + f on the unit square. A membrane of side
1 m, areal density 1 kg/m^2 and tension c^2 N/m under the pressure f (N/m^2 = the study's f
times the density) is the same equation in SI; its force is the film's one Gaussian load
(``live.film.film_load``). The FEM modes (P2, 1/30 m triangles, 100 modes and the static
correction) stepped by the live core must give the exact modal solution's film to 1e-3
(relative L2 over a 21 x 21 lattice and every step).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from membrane_models import fem
from membrane_models.exact import exact_solution
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tables import lattice_points, live_tables
from membrane_models.live.film import film_load
from membrane_models.live.stepper import ModalStepper
from membrane_models.problems import MembraneForced, make_problem

LATTICE = (21, 21)
DT = 0.005


def _film_error(problem: MembraneForced, tension: float, element_size: float) -> float:
    membrane = fem.Membrane(tension=tension, areal_density=1.0)
    system = fem.assemble(fem.rectangle(1.0, 1.0, element_size), membrane, "clamped")
    tables = live_tables(system, fem.modes(system, 100), LATTICE, [1.0 / math.sqrt(problem.k)])
    engine = ModalStepper(fem_basis(tables), DT, hold="foh")
    steps = round(problem.t_end / DT)
    state = engine.start().state
    frames = []
    for index in range(1, steps + 1):
        result = engine.step(state, [film_load(problem, index * DT)])
        state = result.state
        assert result.frame is not None
        frames.append(result.frame)
    points = lattice_points((0.0, 0.0), (1.0, 1.0), LATTICE)
    times = DT * np.arange(1, steps + 1)
    exact = exact_solution(problem).at_points(points, times).T
    return float(np.linalg.norm(np.array(frames) - exact) / np.linalg.norm(exact))


def _problem() -> MembraneForced:
    problem = make_problem("membrane-forced")
    assert isinstance(problem, MembraneForced)
    return problem


@pytest.mark.slow
def test_the_physical_membrane_gives_the_exact_film() -> None:
    problem = _problem()
    assert _film_error(problem, problem.c**2, 1.0 / 30.0) <= 1e-3


@pytest.mark.slow
def test_a_wrong_tension_would_be_caught() -> None:
    """Its power: 1 % more tension (0.5 % on c) moves the film beyond the tolerance."""
    problem = _problem()
    assert _film_error(problem, 1.01 * problem.c**2, 1.0 / 30.0) > 1e-3
