"""Building the modal engine from a scene's ``[live]`` options: the ``modal`` engine kind.

A server builds engines by kind from the ``membrane.engines`` entry-point group, each entry a
callable ``(problem, lattice, dt, options) -> LiveEngine``; this is the built-in one. The
options are the scene's ``[live]`` keys other than ``engine``; each kind checks its own, so a
new kind brings its settings without a change to the scene schema.
"""

from __future__ import annotations

from collections.abc import Mapping

from membrane_models.live.engine import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.live.options import damping_option, modes_option, refuse_unknown
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
    refuse_unknown(options, MODAL_OPTIONS)
    damping = damping_option(options)
    hold = options.get("hold", "zoh")
    if hold not in ("zoh", "foh"):
        raise InvalidEngineSettings('[live] hold must be "zoh" or "foh"')
    modes = modes_option(options, _MAX_MODES, None)
    return ModalEngine(problem, lattice, dt, damping=damping, hold=hold, modes=modes)
