"""What the fem room's tests share: a unit plate, the observed order, the series references."""

from __future__ import annotations

import math

import numpy as np

from membrane_models import fem

NU = 0.3
# A plate with D = 1 N m (E for h = 1 m, nu = 0.3) and rho h = 1 kg/m^2.
UNIT_PLATE = fem.Plate(12 * (1 - NU**2), NU, 1.0, 1.0)


def observed_order(errors: list[float], sizes: list[float]) -> float:
    """log(e1 / e2) / log(h1 / h2) between the last two meshes."""
    return math.log(abs(errors[-2]) / abs(errors[-1])) / math.log(sizes[-2] / sizes[-1])


def navier(
    plate: fem.Plate, q: float, a: float, b: float, x: float, y: float, terms: int = 301
) -> tuple[float, float]:
    """A simply supported a x b plate under uniform q, with its pre-tension and foundation:
    the Navier series' w (m) and M_x (N m/m) at (x, y)."""
    m = np.arange(1, terms, 2, dtype=float)[:, None]
    n = np.arange(1, terms, 2, dtype=float)[None, :]
    s = (m / a) ** 2 + (n / b) ** 2
    d = plate.rigidity
    amp = (
        16
        * q
        / (math.pi**2 * m * n)
        / (d * math.pi**4 * s**2 + plate.pretension * math.pi**2 * s + plate.foundation)
    )
    shape = np.sin(m * math.pi * x / a) * np.sin(n * math.pi * y / b)
    moment = amp * shape * d * math.pi**2 * ((m / a) ** 2 + plate.poisson * (n / b) ** 2)
    return float((amp * shape).sum()), float(moment.sum())


def polar_disk(radii: np.ndarray, spokes: int) -> fem.Domain:
    """A disk meshed on rings: a vertex at the centre, ``spokes`` vertices on each circle of
    ``radii`` (increasing, the last the rim), quads between rings cut in two. Its edges follow
    every ring, so a tool's rim on a ring is resolved exactly."""
    theta = 2 * math.pi * np.arange(spokes) / spokes
    circle = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    points = np.concatenate([np.zeros((1, 2)), *(r * circle for r in radii)])
    j = np.arange(spokes)
    after = (j + 1) % spokes
    triangles = [np.stack([np.zeros(spokes, dtype=int), 1 + j, 1 + after], axis=1)]
    for ring in range(len(radii) - 1):
        inner, outer = 1 + ring * spokes, 1 + (ring + 1) * spokes
        triangles.append(np.stack([inner + j, outer + j, outer + after], axis=1))
        triangles.append(np.stack([inner + j, outer + after, inner + after], axis=1))
    rim = fem.Circle((0.0, 0.0), float(radii[-1]))
    return fem.from_triangles(points, np.concatenate(triangles), curves={"boundary": rim})
