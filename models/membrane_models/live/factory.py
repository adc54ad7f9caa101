"""Building the modal engine from a scene's ``[live]`` options: the ``modal`` engine kind.

A server builds engines by kind from the ``membrane.engines`` entry-point group, each entry a
callable ``(problem, lattice, dt, options) -> LiveEngine``; this is the built-in one. The
options are the scene's ``[live]`` keys other than ``engine``; each kind checks its own, so a
new kind brings its settings without a change to the scene schema.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from membrane_models.live.engine import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.problems import Problem

__all__ = ["MODAL_OPTIONS", "build_modal_engine"]

# Option -> what it is (docs/SCENES.md, "[live]").
MODAL_OPTIONS = {
    "damping": "modal damping ratio zeta, in [0, 1) (default 0)",
    "hold": '"zoh" (loads held over a step, default) or "foh" (ramped from the last step\'s)',
    "modes": "modes stepped per axis, 1 to 1024 (default: those the lattice resolves)",
}
_MAX_MODES = 1024


def build_modal_engine(
    problem: Problem | object, lattice: tuple[int, ...], dt: float, options: Mapping[str, object]
) -> ModalEngine:
    """The exact modal engine on ``lattice`` with step ``dt`` and the scene's options.

    Raises:
        InvalidEngineSettings: an unknown option, or one of the wrong type or range.
    """
    if not isinstance(problem, Problem):
        raise InvalidEngineSettings(
            "the modal engine steps a dimensionless problem; a [tissue] scene's engine is fem"
        )
    unknown = sorted(set(options) - set(MODAL_OPTIONS))
    if unknown:
        known = ", ".join(MODAL_OPTIONS)
        raise InvalidEngineSettings(f"unknown [live] option {unknown[0]!r:.40}; known: {known}")
    damping = options.get("damping", 0.0)
    if isinstance(damping, bool) or not isinstance(damping, int | float):
        raise InvalidEngineSettings("[live] damping must be a number")
    if not (math.isfinite(damping) and 0.0 <= damping < 1.0):
        raise InvalidEngineSettings(f"[live] damping must be in [0, 1), got {damping:.6g}")
    hold = options.get("hold", "zoh")
    if hold not in ("zoh", "foh"):
        raise InvalidEngineSettings('[live] hold must be "zoh" or "foh"')
    modes = options.get("modes")
    if modes is not None and (
        isinstance(modes, bool) or not isinstance(modes, int) or not 1 <= modes <= _MAX_MODES
    ):
        raise InvalidEngineSettings(f"[live] modes must be an integer from 1 to {_MAX_MODES}")
    return ModalEngine(problem, lattice, dt, damping=float(damping), hold=hold, modes=modes)
