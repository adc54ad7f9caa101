"""The plate's surface stress at a point: bending plus the membrane pre-stress, von Mises.

With z up (w positive along +z) and the mid-plane at z = 0, the bending moments per length are

    M_x = -D (w_xx + nu w_yy),  M_y = -D (w_yy + nu w_xx),  M_xy = -D (1 - nu) w_xy   (N m/m)

and the bending stress is linear through the thickness, sigma(z) = 12 M z / h^3: +-6 M / h^2
on the faces (z = +h/2 "top", z = -h/2 "bottom"). The pre-tension T adds T / h to sigma_x and
sigma_y on both faces, and so does a large deflection's membrane force N / h (``membrane``).
von Mises (plane stress): sqrt(sx^2 - sx sy + sy^2 + 3 txy^2) (Pa).
The curvatures are the Argyris field's own second derivatives at the point (``sampling``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidSolve
from membrane_models.fem.models import Plate
from membrane_models.fem.sampling import derivatives

__all__ = ["SurfaceStress", "surface_stress"]


@dataclass(frozen=True)
class SurfaceStress:
    """Stress at one point of a plate.

    Attributes:
        moments: (M_x, M_y, M_xy), N m/m.
        top: von Mises on the face z = +h/2, Pa.
        bottom: von Mises on the face z = -h/2, Pa.
    """

    moments: tuple[float, float, float]
    top: float
    bottom: float

    @property
    def von_mises(self) -> float:
        """The larger face's, Pa."""
        return max(self.top, self.bottom)


def surface_stress(
    system: System,
    u: ArrayLike,
    at: ArrayLike,
    membrane: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> SurfaceStress:
    """The stress of the deflection ``u`` at ``at`` = (x, y) (m); ``membrane``: a large
    deflection's membrane force there, (N_x, N_y, N_xy) N/m (``nonlinear.membrane_force``),
    added as N / h on both faces like the pre-tension."""
    plate = system.model
    if not isinstance(plate, Plate) or system.element != "argyris":
        raise InvalidSolve("surface stress is a plate's, on argyris triangles")
    _, _, hessian = derivatives(system, u, np.asarray(at, dtype=np.float64)[None, :])
    wxx, wxy, wyy = hessian[0, 0, 0], hessian[0, 0, 1], hessian[0, 1, 1]
    d, nu, h = plate.rigidity, plate.poisson, plate.thickness
    mx, my, mxy = -d * (wxx + nu * wyy), -d * (wyy + nu * wxx), -d * (1 - nu) * wxy
    nx, ny, nxy = (
        (plate.pretension + membrane[0]) / h,
        (plate.pretension + membrane[1]) / h,
        membrane[2] / h,
    )
    faces = []
    for side in (1.0, -1.0):
        sx = side * 6 * mx / h**2 + nx
        sy = side * 6 * my / h**2 + ny
        txy = side * 6 * mxy / h**2 + nxy
        faces.append(math.sqrt(max(sx * sx - sx * sy + sy * sy + 3 * txy * txy, 0.0)))
    return SurfaceStress((float(mx), float(my), float(mxy)), faces[0], faces[1])
