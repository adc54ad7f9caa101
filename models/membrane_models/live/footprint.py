"""A load's or a probe's Gaussian footprint, and its sine spectrum per axis.

A footprint of radius r centred at a is normalised over the line,

    g(x) = exp(-(x - a)^2 / r^2) / (sqrt(pi) r),

and over the plane as g(x) g(y) (so F g is the issue's pressure F / (pi r^2) exp(-rho^2 / r^2)).
The modal force per unit total force on the mode prod sin(m pi x) is the product over axes of

    sigma_m = 2 int_0^1 g(x) sin(m pi x) dx,

the 2 being the modes' normalisation (int sin^2 = 1/2). The integral stops at the clamped edges:
the part of the Gaussian beyond them presses on the support. Far from the edges (6.2 r or more,
where they weigh exp(-38) ~ 3e-17) sigma_m = 2 exp(-(m pi r)^2 / 4) sin(m pi a); nearer, each
near edge adds its term of the closed form of ``spectrum.gaussian_sine_integrals`` (a Faddeeva
function per mode: the costly part of a step near an edge).
On the string r = 0 is a point force: sigma_m = 2 sin(m pi a).

How many modes a footprint needs (``gaussian_reach``, ``edge_reach``): the Gaussian part is
below 1e-17 of the first beyond m = 4 / r; a footprint cut by an edge adds a part decaying like
e / m, with e = exp(-(d / r)^2) its weight at the edge (d the distance to it), taken until
e / m^2 <= 1e-8.
Both are capped: the Gaussian part by the engine's ``max_reach`` (below its smallest radius the
engine refuses the footprint), the edge part by ``EDGE_CAP`` modes, where the frame's share of
that part is summed to about log(M) / (2 M^2) of itself (4e-5 at 256) and the compliance's to
1e-8 of it.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import wofz

__all__ = [
    "CACHE_BYTES",
    "EDGE_CAP",
    "EDGE_FREE",
    "Footprint",
    "axis_spectrum",
    "edge_reach",
    "gaussian_reach",
    "make_footprint",
]

FloatArray = NDArray[np.float64]

_GAUSS_REACH = 4.0  # modes up to 4 / r: the Gaussian factor is exp(-4 pi^2) ~ 7e-18 there
EDGE_FREE = 6.2  # radii from an edge beyond which its term is below exp(-38) ~ 3e-17
EDGE_CAP = {1: 2**14, 2: 2**8}  # modes per axis for the edge part: string, membrane
_EDGE_TOLERANCE = 1e-8  # an edge-cut footprint's 1/m part is kept while e / m^2 exceeds this
_CACHE_BYTES = 32 * 2**20  # spectra kept for footprints that come back (a load held in place)
# The Gaussian factors kept: at most 64 of at most 4,096 modes (two arrays each): 4 MiB.
_FACTOR_CACHE_ENTRIES = 64
_FACTOR_CACHED_COUNT = 4096
# What the caches above hold at most, shared by every engine of the process.
CACHE_BYTES = _CACHE_BYTES + _FACTOR_CACHE_ENTRIES * 2 * 8 * _FACTOR_CACHED_COUNT


@dataclass(frozen=True)
class Footprint:
    """Where a load or probe acts and its spectrum along each axis.

    Attributes:
        at: the centre.
        radius: r (0: a point, string only).
        spectra: sigma_1 .. sigma_M per axis (read-only), M at least the kept box's size.
    """

    at: tuple[float, ...]
    radius: float
    spectra: tuple[FloatArray, ...]

    @property
    def is_point(self) -> bool:
        return self.radius == 0.0


@functools.lru_cache(maxsize=256)
def gaussian_reach(radius: float) -> int:
    """Modes per axis the Gaussian part of a footprint of radius ``radius`` > 0 needs."""
    return math.ceil(_GAUSS_REACH / radius)


def edge_reach(centre: float, radius: float) -> int:
    """Modes along one axis that carry the 1/m part of a footprint cut by an edge."""
    distance = min(centre, 1.0 - centre)
    edge = math.exp(-((distance / radius) ** 2))
    return math.ceil(math.sqrt(edge / _EDGE_TOLERANCE))


def axis_spectrum(centre: float, radius: float, count: int, cache: bool = True) -> FloatArray:
    """sigma_1 .. sigma_count along one axis (read-only).

    ``cache``: keep it for the next call with the same arguments (a load held in place); a
    moving probe skips the cache, whose bookkeeping would cost more than the sines.
    """
    key = (centre, radius, count)
    if cache:
        cached = _CACHE.get(key)
        if cached is not None:
            return cached
    factor, phases = _gauss_factor(radius, count)
    values = factor * np.sin(phases * centre)
    if radius > 0.0 and (centre < EDGE_FREE * radius or 1.0 - centre < EDGE_FREE * radius):
        _add_edges(values, centre, radius, phases)
    values.flags.writeable = False
    if cache:
        _CACHE.put(key, values)
    return values


def _add_edges(values: FloatArray, centre: float, radius: float, phases: FloatArray) -> None:
    """The edge terms of the closed form, for the edges nearer than ``EDGE_FREE`` radii.

    With u = m pi r / 2 and delta the distance to an edge in radii, the left edge subtracts
    exp(-delta^2) Im w(-u + i delta), the right one (-1)^m exp(-delta^2) Im w(u + i delta)
    (``spectrum.gaussian_sine_integrals`` with its 2 / (sqrt(pi) r) normalisation).
    """
    u = 0.5 * radius * phases
    left, right = centre / radius, (1.0 - centre) / radius
    if left < EDGE_FREE:
        values -= math.exp(-(left**2)) * wofz(-u + 1j * left).imag
    if right < EDGE_FREE:
        signs = np.where(np.arange(1, u.size + 1) % 2 == 1, -1.0, 1.0)
        values -= signs * math.exp(-(right**2)) * wofz(u + 1j * right).imag


def _gauss_factor(radius: float, count: int) -> tuple[FloatArray, FloatArray]:
    """2 exp(-(m pi r)^2 / 4) and m pi for m = 1 .. count (read-only); short ones cached."""
    if count <= _FACTOR_CACHED_COUNT:
        return _cached_gauss_factor(radius, count)
    return _compute_gauss_factor(radius, count)


@functools.lru_cache(maxsize=_FACTOR_CACHE_ENTRIES)
def _cached_gauss_factor(radius: float, count: int) -> tuple[FloatArray, FloatArray]:
    return _compute_gauss_factor(radius, count)


def _compute_gauss_factor(radius: float, count: int) -> tuple[FloatArray, FloatArray]:
    phases = np.pi * np.arange(1, count + 1, dtype=np.float64)
    factor = 2.0 * np.exp(-((radius * phases) ** 2) / 4.0)
    factor.setflags(write=False)
    phases.setflags(write=False)
    return factor, phases


def make_footprint(
    at: tuple[float, ...], radius: float, counts: tuple[int, ...], cache: bool = True
) -> Footprint:
    """The footprint at ``at`` with ``counts[i]`` spectrum entries along axis i."""
    if len(at) == 1:
        return Footprint(at, radius, (axis_spectrum(at[0], radius, counts[0], cache),))
    x = axis_spectrum(at[0], radius, counts[0], cache)
    return Footprint(at, radius, (x, axis_spectrum(at[1], radius, counts[1], cache)))


class _SpectrumCache:
    """Least recently used spectra, bounded in bytes (a held load is computed once)."""

    def __init__(self, max_bytes: int) -> None:
        self._items: OrderedDict[tuple[float, float, int], FloatArray] = OrderedDict()
        self._bytes = 0
        self._max = max_bytes
        self._lock = threading.Lock()  # engines may step in several threads

    def get(self, key: tuple[float, float, int]) -> FloatArray | None:
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def put(self, key: tuple[float, float, int], value: FloatArray) -> None:
        if value.nbytes > self._max // 4:
            return  # huge spectra (a tiny radius on a string) are not worth the memory
        with self._lock:
            if key in self._items:
                return
            self._items[key] = value
            self._bytes += value.nbytes
            while self._bytes > self._max:
                _, old = self._items.popitem(last=False)
                self._bytes -= old.nbytes


_CACHE = _SpectrumCache(_CACHE_BYTES)
