"""Static deflection under a point load, a uniform pressure or a patch load.

Loads are vectors on the element's DOFs (``(N,)``, generalised forces: the work ``f . u`` is
in J), positive along +z like w:

- ``point_load(system, force, at)``: a force P (N) at one point, exactly: the basis functions'
  values there (``sampling.evaluation``), so f . u = P w(at);
- ``pressure_load(system, pressure)``: a uniform pressure q (Pa) over the domain;
- ``patch_load(system, force, at, radius)``: P spread uniformly over a disk of radius r (m),
  q = P / (pi r^2) there, integrated by a polar Gauss rule finer than the mesh (the disk's edge
  cuts elements, which an element rule would integrate poorly); the disk must lie on the mesh.

``solve(system, load)`` returns the deflection's DOF vector ``u = T K_r^-1 T' f`` (a load
``(N, k)`` gives ``k`` columns); ``sampling.sample`` reads w (m) from it. A membrane's point
load has no continuum limit (the deflection is log-singular): its value depends on the mesh.
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.linalg import splu

from membrane_models.fem import forms
from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidLoad, OutsideDomain
from membrane_models.fem.sampling import evaluation

__all__ = ["patch_load", "point_load", "pressure_load", "solve"]

FloatArray = NDArray[np.float64]


def point_load(system: System, force: float, at: ArrayLike) -> FloatArray:
    """P (N) at ``at`` = (x, y) (m)."""
    _finite("force", force)
    xy = _at(at)
    try:
        probe = evaluation(system, xy[None, :])
    except OutsideDomain as error:
        raise OutsideDomain(
            f"point load at ({xy[0]:.6g}, {xy[1]:.6g}) m is off the mesh"
        ) from error
    return np.asarray(force * probe.toarray()[0], dtype=np.float64)


def pressure_load(system: System, pressure: float) -> FloatArray:
    """A uniform pressure q (Pa) on the whole domain."""
    _finite("pressure", pressure)
    return np.asarray(
        forms.pressure.assemble(system.basis, pressure=float(pressure)), dtype=np.float64
    )


def patch_load(system: System, force: float, at: ArrayLike, radius: float) -> FloatArray:
    """P (N) spread uniformly over the disk of ``radius`` (m) centred at ``at``."""
    _finite("force", force)
    real = isinstance(radius, numbers.Real) and not isinstance(radius, bool)
    if not (real and math.isfinite(radius) and radius > 0):
        raise InvalidLoad(f"a patch's radius must be a positive number of metres, not {radius!r}")
    xy = _at(at)
    ratio = radius / system.domain.size
    rings = max(6, math.ceil(3 * ratio))
    spokes = max(24, 4 * math.ceil(2 * math.pi * ratio))
    nodes, weights = np.polynomial.legendre.leggauss(rings)
    r = 0.5 * radius * (nodes + 1.0)
    w_r = 0.5 * radius * weights * r  # int_0^R g r dr
    theta = 2 * math.pi * (np.arange(spokes) + 0.5) / spokes
    points = (
        xy[:, None, None] + r[None, :, None] * np.stack([np.cos(theta), np.sin(theta)])[:, None, :]
    )
    area_weights = (w_r[:, None] * np.full(spokes, 2 * math.pi / spokes)[None, :]).ravel()
    try:
        probes = evaluation(system, points.reshape(2, -1).T)
    except OutsideDomain as error:
        raise OutsideDomain(
            f"the patch at ({xy[0]:.6g}, {xy[1]:.6g}) m, radius {radius:.6g} m,"
            " reaches off the mesh"
        ) from error
    pressure = force / (math.pi * radius * radius)
    return np.asarray(pressure * (probes.T @ area_weights), dtype=np.float64)


def solve(system: System, load: ArrayLike) -> FloatArray:
    """The deflection's DOF vector under ``load`` ``(N,)`` or ``(N, k)``."""
    f = np.asarray(load, dtype=np.float64)
    if f.shape[0] != system.dofs or f.ndim > 2:
        raise InvalidLoad(f"a load has {system.dofs} rows (the DOFs), not shape {f.shape}")
    if not np.isfinite(f).all():
        raise InvalidLoad("a load must be finite")
    reduced = splu(system.reduced_stiffness).solve(system.reduce(f))
    return system.expand(reduced)


def _finite(name: str, value: float) -> None:
    real = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (real and math.isfinite(value)):
        raise InvalidLoad(f"{name} must be a finite number, not {value!r}")


def _at(at: ArrayLike) -> FloatArray:
    xy = np.asarray(at, dtype=np.float64)
    if xy.shape != (2,) or not np.isfinite(xy).all():
        raise InvalidLoad(f"a load's point is a finite (x, y), not {at!r}")
    return xy
