"""The ``fem`` engine kind: a physical tissue's modes stepped by the live core.

A server builds engines by kind from the ``membrane.engines`` entry-point group, each entry a
callable ``(problem, lattice, dt, options) -> LiveEngine``; for this kind the "problem" is a
``tissue.Tissue`` (a scene's ``[tissue]`` table). The engine is the live core
(``live.stepper.ModalStepper``) over the tissue's FEM basis (``live_basis.fem_basis``), its
tables from the user's cache (``cache.cached_tables``; built and stored on a miss).

Every one of the tissue's modes is stepped, whatever the step: the core's transition is exact
at any w dt, so keeping only the modes with w dt <= pi (about 11 of the skin patch's at 1 ms)
would buy little time and lose their dynamics; the static correction carries the modes beyond.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from membrane_models.fem.cache import cached_tables
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tissue import Tissue
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.live.interface import Hold
from membrane_models.live.options import refuse_unknown
from membrane_models.live.stepper import ModalStepper

__all__ = ["FEM_OPTIONS", "build_fem_engine"]

# Option -> what it is (docs/SCENES.md, "[live]" of a tissue scene).
FEM_OPTIONS = {
    "hold": '"zoh" (loads held over a step, default) or "foh" (ramped from the last step\'s)',
}


class FemEngine(ModalStepper[Any]):
    """The live core over a tissue's FEM modes; ``describe`` names the tissue."""

    def __init__(self, tissue: Tissue, lattice: tuple[int, int], dt: float, hold: Hold) -> None:
        tables, _ = cached_tables(
            tissue.domain,
            tissue.model,
            tissue.supports,
            count=tissue.modes,
            lattice=lattice,
            radii=tissue.radii,
            element=tissue.element,
        )
        self.tissue = tissue
        damping = tissue.damping_ratios(tables.omega)
        super().__init__(
            fem_basis(tables),
            dt,
            damping=damping,
            hold=hold,
            kind="fem",
        )

    def subject(self) -> dict[str, object]:
        return {"tissue": self.tissue.name, "modes_rule": _RULE}


_RULE = (
    "the tissue's lowest modes, every one stepped (the exact transition holds at any w dt); "
    "the static correction carries the rest"
)


def build_fem_engine(
    problem: object, lattice: tuple[int, ...], dt: float, options: Mapping[str, object]
) -> FemEngine:
    """The FEM engine of a tissue scene.

    Raises:
        InvalidEngineSettings: not a tissue, a lattice not 2-D, or an unknown option.
    """
    if not isinstance(problem, Tissue):
        raise InvalidEngineSettings(
            "the fem engine steps a physical tissue: give the scene a [tissue] table"
        )
    refuse_unknown(options, FEM_OPTIONS)
    hold = options.get("hold", "zoh")
    if hold not in ("zoh", "foh"):
        raise InvalidEngineSettings('[live] hold must be "zoh" or "foh"')
    if len(lattice) != 2:
        raise InvalidEngineSettings("a tissue's lattice needs nx and ny")
    return FemEngine(
        problem, (int(lattice[0]), int(lattice[1])), dt, "foh" if hold == "foh" else "zoh"
    )
