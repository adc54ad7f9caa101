"""A live scene's film is its own engine under its own forcing: film and sessions agree."""

from __future__ import annotations

import numpy as np

from membrane_models.exact import exact_solution
from membrane_models.live import film_load
from membrane_models.problems import MembraneForced
from membrane_server.served import ServedScene


def test_membrane_lives_film_is_a_session_driven_by_its_forcing() -> None:
    served = ServedScene.load("membrane-live")
    assert served.evaluator.kind == "engine"
    problem = served.source.problem  # type: ignore[union-attr]
    assert isinstance(problem, MembraneForced)
    engine = served.live
    assert engine is not None
    state = engine.start().state
    dt = served.scene.dt
    for k in range(1, 301):
        result = engine.step(state, [film_load(problem, (k - 0.5) * dt)])  # mid-step, zoh
        state = result.state
    assert result.frame is not None
    film = served.frame(served.timeline.resolve(300 * dt))
    np.testing.assert_array_equal(film, result.frame)  # the same engine, the same loads
    exact = exact_solution(problem).at_points(served.evaluator.points, [300 * dt])[:, 0]
    relative = np.linalg.norm(film - exact) / np.linalg.norm(exact)
    assert 5e-3 < relative < 0.1  # damped (2 %) against the undamped exact film: they differ
