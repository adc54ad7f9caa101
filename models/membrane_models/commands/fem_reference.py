"""Closed-form frequencies for `membrane fem modes`, where the shape and supports have one.

- a fixed membrane (clamped or simply supported: both fix w) rectangle a x b:
  f = c pi sqrt(m^2/a^2 + n^2/b^2) / (2 pi), c = sqrt(T / rho_h);
- a fixed membrane disk of radius R: f = c j_{n,k} / R / (2 pi), j_{n,k} the k-th zero of J_n
  (n >= 1: a pair of modes, cos and sin n theta);
- a simply supported rectangular plate: omega^2 = (D k^4 + T k^2 + k_f) / (rho h),
  k^2 = pi^2 (m^2/a^2 + n^2/b^2) (pre-tension T, foundation k_f);
- a clamped disk plate: omega = lambda^2 / R^2 sqrt(D / rho h), lambda the roots of
  J_n(l) I_n'(l) - I_n(l) J_n'(l) = 0 (n >= 1 in pairs; Leissa, Vibration of Plates, 1969);
- a clamped square plate's first mode: omega = 35.985 / a^2 sqrt(D / rho h) (Leissa).

A foundation k_f adds k_f / (rho h) to a plate's omega^2 (its modes are the same). Frequencies
in Hz, ascending, with their indices; the i-th is meant for the i-th lowest FEM mode.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, special

from membrane_models import fem
from membrane_models.commands.fem_setup import Tissue

__all__ = [
    "CLAMPED_SQUARE_FIRST",
    "Reference",
    "clamped_disk_roots",
    "closed_form",
    "membrane_disk",
    "membrane_rectangle",
    "plate_clamped_disk",
    "plate_clamped_square",
    "plate_simply_supported_rectangle",
]

FloatArray = NDArray[np.float64]
CLAMPED_SQUARE_FIRST = 35.985  # omega a^2 / sqrt(D / rho h), Leissa (1969) table 4.23
_FIXED = ("clamped", "simply_supported")
_SCAN = 0.05  # the clamped disk's root scan step (roots lie about pi apart)


@dataclass(frozen=True)
class Reference:
    """Closed-form frequencies.

    Attributes:
        title: which closed form.
        frequencies: Hz, ascending.
        labels: each frequency's indices ("m=1,n=2", "n=0,k=1").
    """

    title: str
    frequencies: tuple[float, ...]
    labels: tuple[str, ...]


def closed_form(item: Tissue, count: int) -> Reference | None:
    """The closed form of ``item``'s lowest ``count`` modes, or None when it has none."""
    model, support, shape = item.model, item.uniform_support, item.shape
    if support is None:
        return None
    if isinstance(model, fem.Membrane):
        if support not in _FIXED:
            return None
        c = model.wave_speed
        if shape in ("square", "rectangle"):
            a, b = _sides(item)
            return membrane_rectangle(c, a, b, count)
        if shape == "disk":
            return membrane_disk(c, item.dimensions[0] / 2, count)
        return None
    if shape in ("square", "rectangle") and support == "simply_supported":
        return plate_simply_supported_rectangle(model, *_sides(item), count)
    if model.pretension > 0 or support != "clamped":
        return None
    if shape == "disk":
        return plate_clamped_disk(model, item.dimensions[0] / 2, count)
    if shape == "square":
        return plate_clamped_square(model, item.dimensions[0])
    return None


def membrane_rectangle(c: float, a: float, b: float, count: int) -> Reference:
    """A fixed a x b membrane of wave speed ``c`` (m/s)."""
    values, labels = _rectangle_family(lambda k2: c * np.sqrt(k2), a, b, count)
    return Reference("fixed membrane rectangle: c pi sqrt(m^2/a^2 + n^2/b^2)", values, labels)


def membrane_disk(c: float, radius: float, count: int) -> Reference:
    """A fixed membrane disk of wave speed ``c`` (m/s)."""
    roots = _lowest(count, _bessel_zeros)
    values = tuple(c * root / radius / (2 * math.pi) for root, _ in roots)
    return Reference("fixed membrane disk: c j_nk / R", values, tuple(label for _, label in roots))


def plate_simply_supported_rectangle(plate: fem.Plate, a: float, b: float, count: int) -> Reference:
    """A simply supported a x b plate, with its pre-tension and foundation."""
    d, t, k, rho_h = plate.rigidity, plate.pretension, plate.foundation, plate.areal_density

    def omega(k2: FloatArray) -> FloatArray:
        return np.asarray(np.sqrt((d * k2**2 + t * k2 + k) / rho_h), dtype=np.float64)

    values, labels = _rectangle_family(omega, a, b, count)
    title = "simply supported plate: omega^2 = (D k^4 + T k^2 + k) / (rho h)"
    return Reference(title, values, labels)


def plate_clamped_disk(plate: fem.Plate, radius: float, count: int) -> Reference:
    """A clamped disk plate (no pre-tension), with its foundation."""
    roots = _lowest(count, clamped_disk_roots)
    values = tuple(_plate_hz(plate, root**2 / radius**2) for root, _ in roots)
    title = "clamped disk plate: lambda^2 / R^2 sqrt(D / rho h), J_n I_n' = I_n J_n'"
    return Reference(title, values, tuple(label for _, label in roots))


def plate_clamped_square(plate: fem.Plate, side: float) -> Reference:
    """A clamped square plate's first mode (no pre-tension), with its foundation."""
    value = _plate_hz(plate, CLAMPED_SQUARE_FIRST / side**2)
    return Reference("clamped square plate: 35.985 / a^2 sqrt(D / rho h)", (value,), ("1",))


def clamped_disk_roots(n: int, limit: float) -> FloatArray:
    """The roots lambda < ``limit`` of J_n(l) I_n'(l) - I_n(l) J_n'(l), ascending (scaled by
    exp(-l) so that I_n does not overflow: the roots are the same)."""

    def g(x: FloatArray) -> FloatArray:
        scaled_prime = 0.5 * (special.ive(n - 1, x) + special.ive(n + 1, x))
        return np.asarray(special.jv(n, x) * scaled_prime - special.ive(n, x) * special.jvp(n, x))

    def f(x: float) -> float:
        return float(g(np.array(x)))

    grid = np.arange(_SCAN, limit + _SCAN, _SCAN)
    values = g(grid)
    changes = np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0)
    roots = [optimize.brentq(f, grid[i], grid[i + 1], xtol=1e-14) for i in changes]
    return np.array([r for r in roots if r < limit], dtype=np.float64)


def _bessel_zeros(n: int, limit: float) -> FloatArray:
    """The zeros j_{n,k} < ``limit`` of J_n, ascending."""
    wanted = max(1, math.ceil(limit / math.pi) + 1)  # j_{n,k} > (k - 1/4) pi: enough of them
    zeros = special.jn_zeros(n, wanted)
    return np.asarray(zeros[zeros < limit], dtype=np.float64)


def _lowest(count: int, roots: Callable[[int, float], FloatArray]) -> list[tuple[float, str]]:
    """The ``count`` lowest roots over n = 0, 1, ... (n >= 1 twice), with "n=,k=" labels.

    The first limit holds ``count`` roots of n = 0; each n after adds the roots below the
    current count-th lowest, until an n has none (the roots of n grow with n)."""
    limit = 4.0 * (count + 2)
    found = roots(0, limit)
    while found.size < count:
        limit *= 2
        found = roots(0, limit)
    collected = [(float(r), f"n=0,k={k + 1}") for k, r in enumerate(found[:count])]
    limit = collected[-1][0] * (1 + 1e-12)
    n = 1
    while True:
        more = roots(n, limit)
        if more.size == 0:
            break
        for k, r in enumerate(more):
            collected += [(float(r), f"n={n},k={k + 1}")] * 2
        collected.sort()
        collected = collected[:count]
        limit = collected[-1][0] * (1 + 1e-12)
        n += 1
    return collected


def _rectangle_family(
    omega: Callable[[FloatArray], FloatArray], a: float, b: float, count: int
) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The ``count`` lowest omega(k^2) / (2 pi), k^2 = pi^2 (m^2/a^2 + n^2/b^2), omega
    increasing in k^2: m, n <= count suffice (the (j, 1), j <= count, lie below any m > count)."""
    index = np.arange(1, count + 1, dtype=np.float64)
    k2 = math.pi**2 * ((index[:, None] / a) ** 2 + (index[None, :] / b) ** 2)
    order = np.argsort(k2, axis=None, kind="stable")[:count]
    m, n = np.unravel_index(order, k2.shape)
    values = omega(k2.ravel()[order]) / (2 * math.pi)
    labels = tuple(f"m={i + 1},n={j + 1}" for i, j in zip(m, n, strict=True))
    return tuple(float(v) for v in values), labels


def _plate_hz(plate: fem.Plate, wavenumber2: float) -> float:
    """f (Hz) of omega^2 = D kappa^4 / (rho h) + k_f / (rho h), kappa^2 = ``wavenumber2``."""
    omega2 = (plate.rigidity * wavenumber2**2 + plate.foundation) / plate.areal_density
    return math.sqrt(omega2) / (2 * math.pi)


def _sides(item: Tissue) -> tuple[float, float]:
    dims = item.dimensions
    return (dims[0], dims[0]) if item.shape == "square" else (dims[0], dims[1])
