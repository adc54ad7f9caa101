"""Duhamel integrals of the forcing's time bump: how each mode responds to g_a(t).

A mode q'' + w^2 q = g(t), q(0) = q'(0) = 0, driven by the time bump g = g_a (zero outside
[0, 1]) has the response

    q(t) = (1/w) int_0^tau sin(w (t - s)) g(s) ds,      tau = clip(t, 0, 1),
         = (1/w) Im[ exp(i w t) conj(E(tau)) ],          E(tau) = int_0^tau exp(i w s) g(s) ds.

So q is 0 before t = 0 and rings freely (constant E(1)) after the force ends at t = 1.

E is computed by composite Gaussian quadrature: [0, 1] is cut into P equal panels, short enough
that w_max * width <= ``_PHASE_PER_PANEL`` (3 radians) and that the bump is resolved; the
integrals over whole panels are summed once into a table. Inside (0, 1) g_a is smooth and
Gauss-Legendre with 8 points is exact to rounding; at the ends g_a behaves like s^(a-1), not
smooth for non-integer a, so the first and last panels use Gauss-Jacobi rules with that weight
built in (checked against scipy's adaptive quadrature in the tests).

A query at t adds the partial panel [t_j, t] of length l with the same rules. Rather than one
complex exponential per mode and node, it expands exp(i w l u) in powers of (i w l), which is
at most 3 radians: with moments beta_k = sum_q w_q g(s_q) u_q^k shared by all modes,

    int_{t_j}^t exp(i w (s - t_j)) g(s) ds = sum_{k < K} beta_k (i w l)^k / k!,

a short polynomial in w l per mode (K = 30 terms: 3^30 / 30! < 1e-18), evaluated as one small
matrix product with the fixed powers (w / w_max)^k. The table stores
D_j = exp(i w t_j) conj(E(t_j)), so that during the force

    exp(i w t) conj(E(t)) = exp(i w l) (D_j + conj(partial)),

one exponential per mode and query in all.

Memory: the table is (P + 1) x M complex numbers (``BumpResponse.bytes_needed`` predicts what a
response holds); it is built a block of modes at a time, so building needs only a few MiB
beyond it (``_TABLE_BLOCK_BYTES``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import roots_sh_jacobi

from membrane_models.problems import time_bump

__all__ = [
    "BumpResponse",
    "bump_amplitude_factor",
    "bump_integral",
    "quasi_static_constant",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_NODES_PER_PANEL = 8
_PHASE_PER_PANEL = 3.0  # radians of the fastest mode per panel
_TAYLOR_TERMS = 30  # of exp(i x), |x| <= 3: the first term left out is 3^30 / 30! ~ 8e-19
_MIN_PANELS = 16
_PANELS_PER_BUMP_WIDTH = 4  # the bump's width is about 1 / sqrt(8 (a - 1)): resolve it
_BUMP_PEAK = 4.0  # g_a peaks at 4 (t = 1/2) for every a
# Bound on |int_0^tau sin(w (t-s)) g(s) ds| * w: integrating by parts gives
# |g(tau)| + |g(0)| + total variation of g on [0, tau] <= 4 + 4 + 8 (a = 1: 4 + 4 + 0).
_IBP_CONSTANT = 3.0 * _BUMP_PEAK
_ALTERNATING = (-1.0) ** np.arange(_TAYLOR_TERMS // 2)  # i^(2j) = (-1)^j, i^(2j+1) = i (-1)^j
_FACTORIALS = np.array([math.factorial(k) for k in range(_TAYLOR_TERMS)], dtype=np.float64)
# Bytes of complex scratch per evaluation block (bounds memory for many modes x many times).
_BLOCK_BYTES = 32 * 2**20
# Bytes of one (P + 1) x block complex temporary while the table is built; the build holds
# about six such temporaries besides the table itself.
_TABLE_BLOCK_BYTES = 2 * 2**20


def bump_integral(a: float) -> float:
    """int_0^1 g_a(s) ds = 4^a B(a, a)."""
    log_beta = 2.0 * math.lgamma(a) - math.lgamma(2.0 * a)
    return math.exp(a * math.log(4.0) + log_beta)


def bump_amplitude_factor(omega: ArrayLike, a: float) -> FloatArray:
    """Rigorous bound on max_t |q(t)| for a unit-coefficient mode of angular frequency omega.

    |q| <= min(G1 / w, 12 / w^2), with G1 = int g: the first is the impulse bound (slow modes),
    the second comes from one integration by parts (fast modes respond quasi-statically).
    """
    w = np.asarray(omega, dtype=np.float64)
    return np.minimum(bump_integral(a) / w, _IBP_CONSTANT / w**2)


def quasi_static_constant(a: float) -> float | None:
    """E2 such that |q(t) - g(t) / w^2| <= E2 / w^3 for all t, or None when a < 2.

    Integrating the Duhamel integral by parts twice (g(0) = g(1) = 0 for a > 1) leaves
    g(t) / w^2 plus a remainder bounded by (|g'(0)| + |g'(1)| + int_0^1 |g''|) / w^3. For
    a < 2 the derivative g' is unbounded at the ends and the rule does not apply. The total
    variation of g' is summed on a fine grid (exact to about 1e-8 for the smooth g').
    """
    if a < 2.0:
        return None
    t = np.linspace(0.0, 1.0, 20001)
    slope = _bump_slope(t, a)
    variation = float(np.abs(np.diff(slope)).sum())
    return (abs(slope[0]) + abs(slope[-1]) + variation) * (1.0 + 1e-6)


def _bump_slope(t: FloatArray, a: float) -> FloatArray:
    """g_a'(t) = 4^a (a - 1) (t (1 - t))^(a - 2) (1 - 2 t), through logs (no overflow)."""
    if a == 2.0:
        return 16.0 * (1.0 - 2.0 * t)
    inner = np.clip(t * (1.0 - t), 1e-300, None)
    with np.errstate(divide="ignore"):
        log_size = a * math.log(4.0) + math.log(a - 1.0) + (a - 2.0) * np.log(inner)
    return np.exp(log_size) * (1.0 - 2.0 * t)


class BumpResponse:
    """Responses q_m(t) of modes with angular frequencies ``omega`` to the time bump g_a.

    Args:
        omega: angular frequencies, shape (M,), all > 0.
        a: exponent of the time bump (>= 1).
    """

    def __init__(self, omega: ArrayLike, a: float) -> None:
        self.omega = np.ascontiguousarray(omega, dtype=np.float64)
        if self.omega.ndim != 1 or not np.all(self.omega > 0.0):
            raise ValueError("omega must be a 1-D array of positive frequencies")
        self.a = float(a)
        w_max = float(self.omega.max()) if self.omega.size else 1.0
        self.n_panels = int(self.panels_needed(w_max, self.a))
        self.panel_width = 1.0 / self.n_panels
        nodes, weights = np.polynomial.legendre.leggauss(_NODES_PER_PANEL)
        self._legendre = (0.5 * (nodes + 1.0), 0.5 * weights)  # on [0, 1]
        # Gauss-Jacobi on [0, 1] with weights v^(a-1) and (1 - v)^(a-1).
        self._left = roots_sh_jacobi(_NODES_PER_PANEL, self.a, self.a)[:2]
        self._right = roots_sh_jacobi(_NODES_PER_PANEL, self.a, 1.0)[:2]
        self._cumulative = self._panel_table()
        self._w_max = w_max
        # u_q^k / k! at the Legendre nodes: a query's moments are one product with these.
        powers = self._legendre[0][:, None] ** np.arange(_TAYLOR_TERMS)[None, :]
        self._legendre_moments = powers / _FACTORIALS
        self._mode_powers = (self.omega / w_max)[None, :] ** np.arange(_TAYLOR_TERMS)[:, None]

    @staticmethod
    def bytes_needed(n_modes: int, omega_max: float, a: float) -> int:
        """Bytes a response for ``n_modes`` modes up to ``omega_max`` holds (table, powers)."""
        panels = int(BumpResponse.panels_needed(omega_max, a))
        return n_modes * (16 * (panels + 1) + 8 * (_TAYLOR_TERMS + 1))

    @property
    def nbytes(self) -> int:
        """Bytes this response holds."""
        return int(self._cumulative.nbytes + self._mode_powers.nbytes + self.omega.nbytes)

    @staticmethod
    def panels_needed(omega_max: ArrayLike, a: float) -> NDArray[np.int64]:
        """Panels on [0, 1]: enough for the fastest mode's phase and for the bump's width."""
        bump = _PANELS_PER_BUMP_WIDTH * math.sqrt(8.0 * max(a - 1.0, 1.0))
        phase = np.ceil(np.asarray(omega_max, dtype=np.float64) / _PHASE_PER_PANEL)
        return np.maximum(max(_MIN_PANELS, math.ceil(bump)), phase).astype(np.int64)

    # -- quadrature rules: nodes s and weights already multiplied by g(s) ---------------------

    def _interior(self, lo: FloatArray, length: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Gauss-Legendre on [lo, lo + length] (vectors of segments): s and w g(s), (b, Q)."""
        u, w = self._legendre
        s = lo[:, None] + length[:, None] * u[None, :]
        return s, length[:, None] * w[None, :] * time_bump(s, self.a)

    def _from_zero(self, length: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Gauss-Jacobi on [0, length]: g = 4^a s^(a-1) (1-s)^(a-1), s^(a-1) in the rule."""
        v, w = self._left
        s = length[:, None] * v[None, :]
        return s, self._singular_weights(length, w, 1.0 - s)

    def _to_one(self, length: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Gauss-Jacobi on [1 - length, 1], with (1-s)^(a-1) in the rule."""
        v, w = self._right
        s = 1.0 - length[:, None] + length[:, None] * v[None, :]
        return s, self._singular_weights(length, w, s)

    def _singular_weights(
        self, length: FloatArray, w: FloatArray, smooth_base: FloatArray
    ) -> FloatArray:
        """4^a length^a w (smooth_base)^(a-1), through logs; 0 for empty segments."""
        with np.errstate(divide="ignore"):
            log_scale = self.a * (math.log(4.0) + np.log(length))
            log_smooth = (self.a - 1.0) * np.log(np.clip(smooth_base, 1e-300, None))
        values = np.exp(log_scale[:, None] + log_smooth) * w[None, :]
        return np.where(length[:, None] > 0.0, values, 0.0)

    # -- the table and the queries ----------------------------------------------------------

    def _panel_table(self) -> ComplexArray:
        """D_j = exp(i w t_j) conj(E(t_j)) at the panel edges t_j = j h: shape (P + 1, M).

        Built a block of panels by a block of modes at a time, E summed panel by panel along
        each mode (a running carry), so that the temporaries stay at ``_TABLE_BLOCK_BYTES``
        each however many panels (up to millions for a lone fast mode) or modes there are.
        """
        h, n, omega = self.panel_width, self.n_panels, self.omega
        table = np.empty((n + 1, omega.size), dtype=np.complex128)
        table[0] = 0.0  # E(0) = 0
        carry = np.zeros(omega.size, dtype=np.complex128)  # E at the current panel edge
        # exp(i w s) = exp(i w p h) exp(i w (s - p h)): interior panels share their node
        # offsets (taken from panel 1), so their integrals are one (P x Q) @ (Q x M) product.
        offsets = (h + h * self._legendre[0]) - h
        panels = min(n, max(1, _TABLE_BLOCK_BYTES // (16 * _NODES_PER_PANEL)))
        modes = max(1, _TABLE_BLOCK_BYTES // (16 * panels))
        for first in range(0, n, panels):
            index = np.arange(first, min(n, first + panels))
            s, wg = self._panel_nodes(index)
            edges = np.arange(index[0], index[-1] + 2)  # t_j = j h at this block's edges
            times = np.where(edges == n, 1.0, edges.astype(np.float64) * h)
            for lo in range(0, omega.size, modes):
                part = slice(lo, lo + modes)
                rotation = np.exp(1j * np.outer(times, omega[part]))  # exp(i w t_j)
                sums = self._panel_integrals(index, s, wg, offsets, omega[part], rotation[:-1])
                sums[0] += carry[part]  # the running sum, in the order a whole cumsum takes
                np.cumsum(sums, axis=0, out=sums)
                carry[part] = sums[-1]
                np.conj(sums, out=sums)
                table[index + 1, part] = rotation[1:] * sums
        return table

    def _panel_nodes(self, index: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        """Nodes s and weights w g(s) of the panels ``index``: Jacobi rules on the end panels."""
        h, n = self.panel_width, self.n_panels
        s, wg = self._interior(index.astype(np.float64) * h, np.full(index.size, h))
        widths = np.full(1, h)
        if index[0] == 0:
            s[0], wg[0] = (x[0] for x in self._from_zero(widths))
        if index[-1] == n - 1:
            s[-1], wg[-1] = (x[0] for x in self._to_one(widths))
        return s, wg

    def _panel_integrals(
        self,
        index: NDArray[np.int64],
        s: FloatArray,
        wg: FloatArray,
        offsets: FloatArray,
        omega: FloatArray,
        rotation: ComplexArray,
    ) -> ComplexArray:
        """int over each panel of exp(i w s) g(s) ds: shape (panels, modes).

        ``rotation`` is exp(i w t) at each panel's start (panels, modes).
        """
        n = self.n_panels
        out = np.empty((index.size, omega.size), dtype=np.complex128)
        inner = (index > 0) & (index < n - 1)
        local = np.exp(1j * np.outer(offsets, omega))  # (Q, M)
        out[inner] = wg[inner].astype(np.complex128) @ local
        out[inner] *= rotation[inner]
        ends = np.flatnonzero(~inner)
        if ends.size:  # the first and last panels: Jacobi nodes, not shared offsets
            phases = np.exp(1j * s[ends, :, None] * omega)  # (ends, Q, M)
            out[ends] = np.einsum("bqm,bq->bm", phases, wg[ends])
        return out

    def _moments(self, weighted_g: FloatArray, u: FloatArray) -> FloatArray:
        """c_k = sum_q wg_q u_q^k / k! for k < K: shape (n, K), one row per query."""
        powers = u[..., None] ** np.arange(_TAYLOR_TERMS)  # (n, Q, K)
        return np.einsum("nq,nqk->nk", weighted_g, powers) / _FACTORIALS

    def _taylor(self, length: FloatArray, c: FloatArray) -> ComplexArray:
        """sum_k c_k (i w l)^k for every query (lengths l (n,), c (n, K)) and mode: (n, M).

        Written as sum_k [c_k (i l w_max)^k] (w / w_max)^k: the mode powers are a fixed matrix
        with entries in [0, 1], so each query costs one small matrix product.
        """
        scaled = c * (length[:, None] * self._w_max) ** np.arange(_TAYLOR_TERMS)
        parts = np.empty((length.size, 2, _TAYLOR_TERMS))  # real and imaginary coefficients
        parts[:, 0, 0::2] = scaled[:, 0::2] * _ALTERNATING
        parts[:, 0, 1::2] = 0.0
        parts[:, 1, 0::2] = 0.0
        parts[:, 1, 1::2] = scaled[:, 1::2] * _ALTERNATING
        both = parts @ self._mode_powers  # (n, 2, M)
        return both[:, 0] + 1j * both[:, 1]

    def _evaluate(self, t: FloatArray) -> FloatArray:
        """q(t) for a 1-D array of times: shape (n, M)."""
        h, n = self.panel_width, self.n_panels
        out = np.zeros((t.size, self.omega.size))
        panel = np.minimum((np.clip(t, 0.0, 1.0) / h).astype(np.int64), n - 1)
        free = t >= 1.0
        first = (t > 0.0) & (panel == 0) & ~free
        last = (panel == n - 1) & ~free & ~first
        interior = (t > 0.0) & ~(free | first | last)
        table = self._cumulative
        if free.any():  # exp(i w t) conj(E(1)) = exp(i w (t - 1)) D_P
            rotation = np.exp(1j * np.outer(t[free] - 1.0, self.omega))
            out[free] = (rotation * table[n]).imag
        if interior.any():
            start = panel[interior] * h
            length = t[interior] - start
            u, w = self._legendre
            s = start[:, None] + length[:, None] * u[None, :]
            c = self._moments(length[:, None] * w[None, :] * time_bump(s, self.a), u[None, :])
            x = np.outer(length, self.omega)
            partial = self._taylor(length, c)  # int exp(i w (s - t_j)) g ds over [t_j, t]
            out[interior] = (np.exp(1j * x) * (table[panel[interior]] + np.conj(partial))).imag
        if first.any():  # E(t) = partial from 0, and exp(i w t) conj(E(t))
            length = t[first]
            v, _ = self._left
            c = self._moments(self._from_zero(length)[1], v[None, :])
            x = np.outer(length, self.omega)
            out[first] = (np.exp(1j * x) * np.conj(self._taylor(length, c))).imag
        if last.any():  # E(t) = E(1) - int_t^1: exp(i w (t-1)) D_P - conj(tail from t)
            length = 1.0 - t[last]
            v, _ = self._right
            c = self._moments(self._to_one(length)[1], v[None, :])
            x = np.outer(length, self.omega)
            rotation = np.exp(-1j * x)
            out[last] = (rotation * table[n] - np.conj(self._taylor(length, c))).imag
        return out / self.omega

    def __call__(self, t: ArrayLike) -> FloatArray:
        """q_m(t) for unit forcing coefficients: shape (M, nt); 0 for t <= 0."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.empty((self.omega.size, t.size))
        block = max(1, _BLOCK_BYTES // (8 * _TAYLOR_TERMS * max(1, self.omega.size)))
        for lo in range(0, t.size, block):
            out[:, lo : lo + block] = self._evaluate(t[lo : lo + block]).T
        return out

    def at(self, t: float) -> FloatArray:
        """q_m at one time, shape (M,): the per-frame path (interior panels without masks)."""
        t = float(t)
        h, n = self.panel_width, self.n_panels
        panel = int(t / h) if 0.0 < t < 1.0 else 0
        if not 0 < panel < n - 1:  # before, after or in an end panel: the general path
            return self._evaluate(np.array([t]))[0]
        start = panel * h
        length = t - start
        u, w = self._legendre
        weighted_g = length * w * time_bump(start + length * u, self.a)
        c = weighted_g @ self._legendre_moments  # (K,)
        partial = self._taylor(np.array([length]), c[None, :])[0]
        rotation = np.exp(1j * length * self.omega)
        return np.asarray(
            (rotation * (self._cumulative[panel] + np.conj(partial))).imag / self.omega
        )
