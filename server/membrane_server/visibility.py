"""Will the spheres visibly move? A check made when a scene is served.

The problems are nondimensional and their forced responses peak near 5e-4: with the default
placement ``scale = 1`` the spheres move by a few ten-thousandths of a world unit and a viewer
sees nothing, with no error anywhere. ``invisible_motion`` compares the largest displacement, as
placed (``|scale| * peak``), with the spacing between neighbouring spheres (``size`` times the
lattice spacing) and words a warning when it is below ``VISIBLE_FRACTION`` of it.
"""

from __future__ import annotations

import numpy as np

from membrane_server.evaluators import Evaluator
from membrane_server.scene import Scene

__all__ = ["MAX_SAMPLED_FRAMES", "VISIBLE_FRACTION", "invisible_motion", "lattice_spacing"]

# A tenth of the distance between neighbouring spheres: the built-in forced scenes (scale 100)
# move by about one spacing at the peak, the same scenes at scale 1 by about a hundredth.
VISIBLE_FRACTION = 0.1
# The peak is looked for on at most this many evenly spaced steps: a lookup each for the table
# and exact evaluators, one graph run each for a network (well under a second at load).
MAX_SAMPLED_FRAMES = 201


def lattice_spacing(points: np.ndarray) -> float | None:
    """The smallest gap between distinct coordinates along any axis (problem units); None for a
    single point. For a grid this is the grid spacing."""
    gaps = [np.diff(np.unique(points[:, axis])) for axis in range(points.shape[1])]
    positive = [float(g.min()) for g in gaps if g.size]
    return min(positive) if positive else None


def invisible_motion(scene: Scene, evaluator: Evaluator) -> str | None:
    """A one-line warning when the scene's motion, as placed, is too small to see; else None.
    Films only: a physical scene is placed at its true size (scale 1) and moves as its
    sessions press it, which no film can foresee."""
    if not scene.film:
        return None
    spacing = lattice_spacing(evaluator.points)
    if spacing is None:
        return None
    world_spacing = scene.placement.size * spacing
    steps = np.unique(np.linspace(0, scene.last_step, MAX_SAMPLED_FRAMES).round().astype(int))
    peak = max(float(np.max(np.abs(evaluator.frame(int(k) * scene.dt)))) for k in steps)
    moved = abs(scene.placement.scale) * peak
    if peak == 0.0 or moved >= VISIBLE_FRACTION * world_spacing:
        return None  # nothing moves at all (a different problem), or it shows
    needed = VISIBLE_FRACTION * world_spacing / peak
    return (
        f"{scene.where}: spheres move by at most {moved:.3g} world units (peak displacement "
        f"{peak:.3g} x placement.scale {scene.placement.scale:g}), under a tenth of their "
        f"spacing {world_spacing:.3g}: the motion will not show; set placement.scale to "
        f"{needed:.3g} or more (the built-in scenes use 100; docs/SCENES.md)"
    )
