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
