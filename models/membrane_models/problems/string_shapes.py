"""Initial shapes of a string with fixed ends, as sine coefficients: the datasets' families.

A shape is u(x) = sum_{n <= N} b_n sin(n pi x), every b_n in closed form:

- ``square``: a pulse of height 1 on [a, b] whose edges are smoothed by a Gaussian of standard
  deviation ``square_width``: b_n = 2 (cos n pi a - cos n pi b) / (n pi) exp(-(n pi w)^2 / 2).
  Unsmoothed, its int u_x^2 (and so the Kirchhoff string's tension) would be infinite.
- ``sine``: sin(m pi x), m drawn from 1..``max_sine_mode``.
- ``noise``: band-limited white noise: b_n ~ N(0, 1) for n <= ``noise_modes``, zero above.
- ``pluck``: the triangle of height 1 with its apex at x0, b_n = 2 sin(n pi x0) / ((n pi)^2
  x0 (1 - x0)), kinked: its first N modes (the dropped tail is at most 2 / (pi^2 x0 (1 - x0) N)
  of the height; the kinked shape proper has a Dirac in u_xx that no grid resolves).
- ``pluck-smooth``: that triangle smoothed by a Gaussian of standard deviation
  ``pluck_smoothing`` (as ``string-plucked-smooth``).

Smoothing the odd 2-periodic extension by a Gaussian multiplies b_n by exp(-(n pi s)^2 / 2),
its Fourier transform, and keeps the ends fixed. Shapes are drawn with a numpy Generator, so a
seed fixes them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.problems.base import InvalidProblem

__all__ = ["FAMILIES", "ShapeParameters", "draw_shape", "pluck", "smoothing", "square_pulse"]

FloatArray = NDArray[np.float64]

FAMILIES = ("square", "sine", "noise", "pluck", "pluck-smooth")


@dataclass(frozen=True)
class ShapeParameters:
    """What the families' shapes depend on beyond their random draws."""

    square_width: float = 0.02
    pluck_smoothing: float = 0.02
    noise_modes: int = 16
    max_sine_mode: int = 8

    def __post_init__(self) -> None:
        for name in ("square_width", "pluck_smoothing"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidProblem(f"{name} must be a number > 0, got {value}")
        for name in ("noise_modes", "max_sine_mode"):
            if getattr(self, name) < 1:
                raise InvalidProblem(f"{name} must be >= 1, got {getattr(self, name)}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _n(modes: int) -> FloatArray:
    return np.arange(1, modes + 1, dtype=np.float64)


def smoothing(modes: int, sigma: float) -> FloatArray:
    """exp(-(n pi sigma)^2 / 2): a Gaussian smoothing's factor on each sine coefficient."""
    return np.exp(-0.5 * (math.pi * sigma * _n(modes)) ** 2)


def square_pulse(start: float, end: float, width: float, modes: int) -> FloatArray:
    """The pulse of height 1 on [start, end], edges smoothed over ``width`` (a Gaussian's s.d.)."""
    n = _n(modes)
    raw = 2.0 * (np.cos(math.pi * n * start) - np.cos(math.pi * n * end)) / (math.pi * n)
    return np.asarray(raw * smoothing(modes, width))


def pluck(apex: float, modes: int, sigma: float = 0.0) -> FloatArray:
    """The triangle of height 1 with its apex at ``apex``, smoothed when ``sigma`` > 0."""
    n = _n(modes)
    raw = 2.0 * np.sin(math.pi * n * apex) / ((math.pi * n) ** 2 * apex * (1.0 - apex))
    return np.asarray(raw * smoothing(modes, sigma)) if sigma > 0.0 else np.asarray(raw)


def draw_shape(
    family: str, rng: np.random.Generator, modes: int, params: ShapeParameters
) -> tuple[FloatArray, dict[str, Any]]:
    """One shape of a family: its ``modes`` sine coefficients and what was drawn."""
    if family == "square":
        centre, length = rng.uniform(0.25, 0.75), rng.uniform(0.1, 0.4)
        start, end = centre - length / 2, centre + length / 2
        drawn: dict[str, Any] = {"start": start, "end": end, "width": params.square_width}
        return square_pulse(start, end, params.square_width, modes), drawn
    if family == "sine":
        mode = int(rng.integers(1, params.max_sine_mode + 1))
        coeffs = np.zeros(modes)
        if mode <= modes:
            coeffs[mode - 1] = 1.0
        return coeffs, {"mode": mode}
    if family == "noise":
        band = min(params.noise_modes, modes)
        coeffs = np.zeros(modes)
        coeffs[:band] = rng.standard_normal(band)
        return coeffs, {"band": band}
    if family in ("pluck", "pluck-smooth"):
        apex = rng.uniform(0.1, 0.9)
        sigma = params.pluck_smoothing if family == "pluck-smooth" else 0.0
        return pluck(apex, modes, sigma), {"apex": apex, "smoothing": sigma}
    raise InvalidProblem(f"unknown shape family {family!r}; known: {', '.join(FAMILIES)}")
