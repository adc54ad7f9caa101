"""A physical scene's parts: its tissue, what ``describe`` says of it, and its rest-shape film.

A scene with a ``[tissue]`` table serves live sessions on the FEM engine in SI units and has
no film: ``query`` answers the rest shape (zeros) at any time, so protocol v1 clients keep
working, and ``describe`` says ``film: false`` with a one-step time grid (``duration`` = dt).
The lattice is the scene's grid over the tissue's bounding box, in m; points outside the
shape stay at rest, and ``describe``'s ``triangles`` (the lattice's, on the tissue only) let a
viewer draw the shape without them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from membrane_models.fem import FemError
from membrane_models.fem.lattice_surface import lattice_triangles
from membrane_models.fem.tissue import Tissue
from membrane_server.evaluators import Evaluator
from membrane_server.scene import Scene

__all__ = ["SI_STEP_UNITS", "SI_UNITS", "RestEvaluator", "TissueSource", "tissue_parts"]

SI_UNITS = {
    "time": "s (simulation time; t = step * dt)",
    "lattice": "m (the tissue's own coordinates)",
    "displacement": "m, along the placement's axis",
    "force": "N",
    "length": "m",
    "world": "simulator units: origin + size * lattice coordinate, + scale * displacement",
}
SI_STEP_UNITS = {
    "at": "m (the tissue's coordinates)",
    "force": "N, total; a load's > 0 pushes along +axis",
    "depth": "m below the rest surface (a probe presses along -axis)",
    "radius": "m (0: a point force, plates only)",
    "k": "steps taken; t = k * dt",
}


@dataclass(frozen=True)
class TissueSource:
    """What a physical scene's model is: its tissue (``describe``'s ``model``)."""

    tissue: Tissue

    @property
    def spatial_bounds(self) -> list[tuple[float, float]]:
        lower, upper = self.tissue.lower, self.tissue.upper
        return [(lower[0], upper[0]), (lower[1], upper[1])]

    def summary(self) -> dict[str, Any]:
        return self.tissue.describe()

    def lattice_triangles(self, points: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        """The lattice's triangles over the tissue (``describe``'s ``triangles``)."""
        return lattice_triangles(points, shape, self.tissue.domain)


class RestEvaluator(Evaluator):
    """A physical scene's ``query``: the rest shape, at any time (it has no film)."""

    kind = "rest"

    def __init__(self, points: np.ndarray) -> None:
        super().__init__(points)
        self._rest = np.zeros(self.n_points)
        self._rest.setflags(write=False)

    def frame(self, t: float) -> np.ndarray:
        return self._rest

    def info(self) -> dict[str, Any]:
        return {"kind": self.kind, "film": False}


def tissue_parts(scene: Scene) -> tuple[Tissue, TissueSource, RestEvaluator]:
    """Mesh the scene's tissue; its source and rest evaluator on the scene's lattice.

    Raises:
        SceneError: the fem room refused the tissue (naming the scene's file).
    """
    assert scene.tissue is not None
    folder = None if scene.source is None else scene.source.parent
    try:
        tissue = scene.tissue.build(folder)
    except FemError as exc:
        raise scene.error(ValueError(f"tissue: {exc}")) from None
    source = TissueSource(tissue)
    points = scene.lattice.coordinates(source.spatial_bounds)
    return tissue, source, RestEvaluator(points)
