"""Sine spectrum of the Gaussian force profile, and rigorous bounds on it.

The forced problems load the domain with G(x) = exp(-k (x - x0)^2) along each axis (the membrane's
profile is the product of one such factor per axis). Their modal series need the sine integrals

    I_n = int_0^1 G(x) sin(n pi x) dx,

given here in closed form through the Faddeeva function w(z) = exp(-z^2) erfc(-i z), which stays
finite for every n, k and x0 (no overflowing erf of complex arguments):

    int_0^1 G(x) exp(i b x) dx = sqrt(pi) / (2 sqrt(k)) * [ 2 exp(i b x0 - b^2 / (4k))
                                   - exp(-k x0^2) w(i w0) - exp(-k (1 - x0)^2) exp(i b) w(i w1) ],
    w0 = sqrt(k) x0 + i b / (2 sqrt(k)),  w1 = sqrt(k) (1 - x0) - i b / (2 sqrt(k)),  b = n pi.

Bound used to choose and truncate modes (proved in docs/PHYSICS.md): for every n >= 1,

    |I_n| <= gamma_n + A / n,   gamma_n = sqrt(pi / k) exp(-(n pi)^2 / (4k)),
                                A = 2 (G(0) + G(1)) / pi.

The Gaussian part gamma_n is the spectrum of the untruncated Gaussian; A / n comes from the
profile not vanishing at the ends of the interval (exp(-16) ~ 1e-7 for the defaults).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erfc, wofz

__all__ = ["GaussianProfile", "gaussian_sine_integrals"]

FloatArray = NDArray[np.float64]


def gaussian_sine_integrals(n: ArrayLike, x0: float, k: float) -> FloatArray:
    """I_n = int_0^1 exp(-k (x - x0)^2) sin(n pi x) dx, for integer mode numbers ``n``."""
    b = np.pi * np.asarray(n, dtype=np.float64)
    root_k = math.sqrt(k)
    w0 = root_k * x0 + 0.5j * b / root_k
    w1 = root_k * (1.0 - x0) - 0.5j * b / root_k
    inner = (
        2.0 * np.exp(1j * b * x0 - b**2 / (4.0 * k))
        - math.exp(-k * x0**2) * wofz(1j * w0)
        - math.exp(-k * (1.0 - x0) ** 2) * np.exp(1j * b) * wofz(1j * w1)
    )
    return np.asarray((math.sqrt(math.pi) / (2.0 * root_k) * inner).imag, dtype=np.float64)


@dataclass(frozen=True)
class GaussianProfile:
    """One axis of the force profile: exp(-k (x - x0)^2) on [0, 1], with its spectral bounds."""

    x0: float
    k: float

    @property
    def boundary_amplitude(self) -> float:
        """A = 2 (G(0) + G(1)) / pi: the coefficient of the 1/n part of the bound."""
        ends = math.exp(-self.k * self.x0**2) + math.exp(-self.k * (1.0 - self.x0) ** 2)
        return 2.0 * ends / math.pi

    def coefficients(self, n_max: int) -> FloatArray:
        """I_n for n = 1 .. n_max."""
        return gaussian_sine_integrals(np.arange(1, n_max + 1), self.x0, self.k)

    def gauss_bound(self, n: ArrayLike) -> FloatArray:
        """gamma_n = sqrt(pi / k) exp(-(n pi)^2 / (4k)), decreasing in n."""
        n = np.asarray(n, dtype=np.float64)
        return np.asarray(math.sqrt(math.pi / self.k) * np.exp(-((n * np.pi) ** 2) / (4 * self.k)))

    def gauss_tail(self, n: int) -> float:
        """Upper bound on sum_{j > n} gamma_j (<= the integral of gamma from n to infinity)."""
        return float(erfc(n * math.pi / (2.0 * math.sqrt(self.k))))

    def bound(self, n: ArrayLike) -> FloatArray:
        """Upper bound on |I_n|: gamma_n + A / n."""
        n = np.asarray(n, dtype=np.float64)
        return self.gauss_bound(n) + self.boundary_amplitude / n
