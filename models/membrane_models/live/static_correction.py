"""The static correction: the modes not stepped still carry their static compliance.

A localised load excites every mode; the fast ones respond quasi-statically, q = p / w^2. Mode
truncation drops that compliance and makes a probe far too stiff. The mode-acceleration
(residual flexibility) correction adds it back: at the end of each step the response of the
modes not stepped is their static response to the forces acting then,

    u_res(x) = sum_{k not stepped} p_k phi_k(x) / w_k^2,    p_k = F s_k (footprint's modal force),

which enters the frame, the displacement under every probe and the probes' one-step compliance.
For two footprints a and b the residual cross-compliance (displacement under b per unit force
at a) is

    r(a, b) = 2^-d sum_{k not stepped} s_a,k s_b,k / w_k^2,

a quadratic form in the per-axis spectra with the weights W = 1 / w^2 off the stepped set (0 on
it): sigma_a,x sigma_b,x . W . sigma_a,y sigma_b,y on the membrane, two small products. The sum
runs as far as the footprints' spectra reach (``footprint.gaussian_reach`` and ``edge_reach``),
at most ``max_reach`` modes per axis; W is tabulated once up to the reach used so far, doubling
when a footprint needs more (at most 8 MiB at the membrane's default cap, 2 MiB on the string).

A point force on the string (r = 0) has no spectral decay; there the full static response has
the closed form G(x, a) = min(x, a) (1 - max(x, a)) / c^2, and the stepped modes' part is
subtracted from it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.footprint import Footprint, axis_spectrum
from membrane_models.live.modes import ModeSet, omega_box
from membrane_models.live.synthesis import LatticeSynthesis

__all__ = ["ResidualFlexibility", "string_green"]

FloatArray = NDArray[np.float64]


def string_green(x: FloatArray | float, a: float, c: float) -> FloatArray:
    """Static deflection of the clamped string under a unit point force at ``a``."""
    x = np.asarray(x, dtype=np.float64)
    return np.asarray(np.minimum(x, a) * (1.0 - np.maximum(x, a)) / c**2)


class ResidualFlexibility:
    """The static compliance of the modes an engine does not step.

    Args:
        c: wave speed.
        modes: the stepped modes.
        max_reach: most modes per axis the correction sums.
        enabled: False: no correction (everything is 0), for comparisons.
    """

    def __init__(self, c: float, modes: ModeSet, max_reach: int, enabled: bool) -> None:
        self.c = c
        self.modes = modes
        self.dims = len(modes.box)
        self.max_reach = max_reach
        self.enabled = enabled
        self._scale = 0.5**self.dims
        self._weights = self._table(modes.box)

    @property
    def nbytes(self) -> int:
        return int(self._weights.nbytes)

    def weights(self, counts: tuple[int, ...]) -> FloatArray:
        """W on modes 1 .. counts[i] per axis: 1 / w^2 off the stepped set, 0 on it."""
        have = self._weights.shape
        if any(n > h for n, h in zip(counts, have, strict=True)):  # grow by doubling
            pairs = zip(counts, have, strict=True)
            grown = tuple(max(n, min(self.max_reach, 2 * h)) for n, h in pairs)
            self._weights = self._table(grown)
        if self.dims == 1:
            return self._weights[: counts[0]]
        return self._weights[: counts[0], : counts[1]]

    def cross(self, a: Footprint, b: Footprint) -> float:
        """r(a, b): displacement under footprint b per unit force on footprint a, not stepped."""
        if not self.enabled:
            return 0.0
        if a.is_point or b.is_point:
            return self._cross_points(a, b)
        sa, sb = a.spectra, b.spectra
        if self.dims == 1:
            n = min(len(sa[0]), len(sb[0]))
            return self._scale * float(np.dot(sa[0][:n] * sb[0][:n], self.weights((n,))))
        nx, ny = min(len(sa[0]), len(sb[0])), min(len(sa[1]), len(sb[1]))
        w = self.weights((nx, ny))
        return self._scale * float((sa[0][:nx] * sb[0][:nx]) @ w @ (sa[1][:ny] * sb[1][:ny]))

    def combined(self, applied: Sequence[tuple[Footprint, float]]) -> FloatArray:
        """The residual field's modal coefficients of several Gaussian footprints at once,
        sum F s_k / w_k^2, on the box of the longest spectra (one matrix product on the
        membrane: the sum of the footprints' outer products is S_x^T diag(F) S_y)."""
        counts = tuple(max(len(fp.spectra[a]) for fp, _ in applied) for a in range(self.dims))
        w = self.weights(counts)
        if self.dims == 1:
            total = np.zeros(counts[0])
            for footprint, force in applied:
                spectrum = footprint.spectra[0]
                total[: len(spectrum)] += force * spectrum
            return np.asarray(total * w)
        sx = np.zeros((len(applied), counts[0]))
        sy = np.zeros((len(applied), counts[1]))
        for row, (footprint, force) in enumerate(applied):
            x, y = footprint.spectra
            sx[row, : len(x)] = force * x
            sy[row, : len(y)] = y
        return np.asarray((sx.T @ sy) * w)

    def against(self, coefficients: FloatArray, footprint: Footprint) -> float:
        """The displacement under ``footprint`` of a residual field given by its modal
        ``coefficients`` (``combined``'s): 2^-d s . coefficients, as far as both reach."""
        if self.dims == 1:
            n = min(len(coefficients), len(footprint.spectra[0]))
            return self._scale * float(np.dot(footprint.spectra[0][:n], coefficients[:n]))
        x, y = footprint.spectra
        nx, ny = min(coefficients.shape[0], len(x)), min(coefficients.shape[1], len(y))
        return self._scale * float(x[:nx] @ coefficients[:nx, :ny] @ y[:ny])

    def own(self, footprint: Footprint) -> float:
        """r(a, a): the footprint's own residual compliance (the probe's, every step)."""
        if not self.enabled:
            return 0.0
        if footprint.is_point:
            return self._cross_points(footprint, footprint)
        spectra = footprint.spectra
        x = spectra[0] * spectra[0]
        if self.dims == 1:
            return self._scale * float(np.dot(x, self.weights((len(x),))))
        y = spectra[1] * spectra[1]
        return self._scale * float(x @ self.weights((len(x), len(y))) @ y)

    def _cross_points(self, a: Footprint, b: Footprint) -> float:
        """The string with a point force: closed form for two points, else the sum as far as
        the other footprint's spectrum reaches."""
        if a.is_point and b.is_point:
            return self._point_pair(a.at[0], b.at[0])
        point, other = (a, b) if a.is_point else (b, a)
        n = len(other.spectra[0])
        spectrum = axis_spectrum(point.at[0], 0.0, n) if point.spectra[0].any() else np.zeros(n)
        return self._scale * float(np.dot(spectrum * other.spectra[0], self.weights((n,))))

    def coefficients(self, footprint: Footprint, force: float) -> FloatArray:
        """The residual field's modal coefficients F s_k / w_k^2 (box of the spectra's size)."""
        counts = tuple(len(s) for s in footprint.spectra)
        w = self.weights(counts)
        if self.dims == 1:
            return force * footprint.spectra[0] * w
        return force * w * np.outer(footprint.spectra[0], footprint.spectra[1])

    def point_field(self, a: float, force: float, synthesis: LatticeSynthesis) -> FloatArray:
        """The residual field of a point force on the string, at the lattice (closed form)."""
        n = synthesis.shape[0]
        x = np.linspace(0.0, 1.0, n)
        full = string_green(x, a, self.c)
        count = self.modes.box[0]
        stepped = axis_spectrum(a, 0.0, count) * self._stepped_weights()
        return np.asarray(force * (full - synthesis.sines(0, count) @ stepped))

    def _point_pair(self, a: float, b: float) -> float:
        count = self.modes.box[0]
        stepped = axis_spectrum(a, 0.0, count) * axis_spectrum(b, 0.0, count)
        full = float(string_green(b, a, self.c))
        return full - self._scale * float(np.dot(stepped, self._stepped_weights()))

    def _stepped_weights(self) -> FloatArray:
        """1 / w^2 on the stepped modes, 0 elsewhere (the string's box)."""
        return np.where(self.modes.kept, 1.0 / self.modes.omega**2, 0.0)

    def _table(self, counts: tuple[int, ...]) -> FloatArray:
        omega = omega_box(self.c, counts)
        weights = 1.0 / omega**2 if self.enabled else np.zeros(counts)
        kept = tuple(slice(0, min(n, k)) for n, k in zip(counts, self.modes.box, strict=True))
        weights[kept] = np.where(self.modes.kept[kept], 0.0, weights[kept])
        weights.setflags(write=False)
        return weights
