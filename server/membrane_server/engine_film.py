"""A live scene's film from its own engine, so that the film and a session agree.

A live scene on a forced problem (``membrane-live``, ``rope-live``) serves a film besides its
sessions. Answered by the exact (undamped, continuous-time) solution, the film and a session
fed the same forcing differ by the session's damping and hold (2.2-2.5 % on ``membrane-live``).
Here the film is the scene's engine, stepped once at load from rest by the problem's forcing as
one live load (``live.film.film_load``): under a zero-order hold sampled at each step's middle
(the hold's second-order choice), under a first-order hold at each step's end (its ramp
interpolates them). A session stepped with those loads gives the film's frames exactly.

Frames are kept for every step of the film (the scene's ``duration / dt + 1``: ``membrane-live``
holds 1,001 frames of 400 points, 3.2 MB), counted against the scene's ``table_max_bytes``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from membrane_models.live import LiveEngine, film_load
from membrane_models.problems import MembraneForced, Problem, StringForced
from membrane_server.evaluators import Evaluator
from membrane_server.scene import Scene, SceneError

__all__ = ["EngineFilmEvaluator", "films_from_engine"]


def films_from_engine(problem: Problem, engine: LiveEngine[Any] | None) -> bool:
    """Whether a scene's film comes from its engine: a live scene on a forced problem."""
    return engine is not None and isinstance(problem, StringForced | MembraneForced)


class EngineFilmEvaluator(Evaluator):
    """The film of a live scene's engine under the scene's own forcing (module docstring)."""

    kind = "engine"

    def __init__(
        self, scene: Scene, problem: StringForced | MembraneForced, engine: LiveEngine[Any]
    ) -> None:
        super().__init__(scene.lattice.coordinates([(0.0, 1.0)] * problem.spatial_dims))
        steps = scene.last_step
        needed = 8 * (steps + 1) * self.n_points
        if needed > scene.table_max_bytes:
            raise SceneError(
                f"{scene.where}: the engine's film needs {needed} bytes of frames, more than "
                f"table_max_bytes ({scene.table_max_bytes})"
            )
        hold = str(engine.describe().get("hold", "zoh"))
        offset = 0.5 if hold == "zoh" else 0.0  # where in each step the load is sampled
        frames = np.empty((steps + 1, self.n_points))
        state = engine.start().state
        frames[0] = engine.frame(state)
        for k in range(1, steps + 1):
            load = film_load(problem, (k - offset) * scene.dt)
            result = engine.step(state, [load])
            state = result.state
            assert result.frame is not None
            frames[k] = result.frame
        frames.setflags(write=False)
        self._frames, self._dt, self._hold = frames, scene.dt, hold

    def frame(self, t: float) -> np.ndarray:
        index = min(max(round(t / self._dt), 0), self._frames.shape[0] - 1)
        return self._frames[index]

    def info(self) -> dict[str, Any]:
        sampled = "mid-step" if self._hold == "zoh" else "step ends"
        return {
            "kind": self.kind,
            "frames": int(self._frames.shape[0]),
            "memory_bytes": int(self._frames.nbytes),
            "forcing": f"the problem's, one live load sampled at {sampled} ({self._hold} hold)",
        }
