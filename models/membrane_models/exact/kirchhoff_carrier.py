"""The Kirchhoff-Carrier string: tension that grows with stretch, solved in sine modes.

    u_tt = (c^2 + k S(t)) u_xx,   S(t) = int_0^1 u_x^2 dx,   u(0, t) = u(1, t) = 0.

u_xx of a sine series is a sine series, so with u = sum_{n <= N} q_n(t) sin(n pi x) the Galerkin
system

    q_n'' = -(c^2 + k S) (n pi)^2 q_n,   S = sum_n (n pi)^2 q_n^2 / 2,

is the PDE itself, not an approximation of it: the modes couple only through the one scalar S,
and a mode that starts at rest at zero stays zero, so initial data in N modes evolve exactly in
those N modes. The energy

    E = sum_n p_n^2 / 4 + c^2 S / 2 + k S^2 / 4       (p_n = q_n')

is conserved; it bounds the stretch by S* (the S at which all of E is potential), and
k S* / c^2 is the nonlinearity: the relative tension rise at the largest stretch the motion can
reach. One mode alone is a Duffing oscillator whose frequency grows with its amplitude
(``frequency_ratio``). The system is integrated with scipy's DOP853.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp
from scipy.special import ellipk

from membrane_models.budget import check_budget
from membrane_models.exact.solution import ExactSolution, InvalidQuery, PointFrames
from membrane_models.problems import InvalidProblem, StringKirchhoff

__all__ = [
    "DEFAULT_RTOL",
    "KirchhoffReference",
    "KirchhoffSolution",
    "KirchhoffString",
    "frequency_ratio",
    "sine_basis",
    "solve_kirchhoff",
]

FloatArray = NDArray[np.float64]

# DOP853's tolerance. solve_ivp bounds the RMS of the scaled errors, so one component may
# exceed it by sqrt(components): at 1e-12, u_t (a sum over all modes' p_n) was 3e-10 off a
# 2.5e-14 run; at 1e-13 u and u_t are within 3e-11 (tests/models/exact/test_kirchhoff_carrier.py).
DEFAULT_RTOL = 1e-13


@dataclass(frozen=True)
class KirchhoffString:
    """The string's parameters: wave speed c and stretch coefficient k (k = 0: linear).

    Nondimensional, on x in [0, 1] with fixed ends. With position and displacement in units of
    the length: c^2 = T0 / (rho A) and k / c^2 = E A / (2 T0), E A the axial stiffness and T0
    the tension at rest; a slack rope has a large k / c^2. Bad values raise ``InvalidProblem``.
    """

    c: float = 1.0
    k: float = 100.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.c) and self.c > 0.0):
            raise InvalidProblem(f"c must be a finite number > 0, got {self.c}")
        if not (math.isfinite(self.k) and self.k >= 0.0):
            raise InvalidProblem(f"k must be a finite number >= 0, got {self.k}")

    def stretch(self, q: ArrayLike) -> FloatArray:
        """S = int u_x^2 dx = sum (n pi)^2 q_n^2 / 2 over the last axis (modes 1..N)."""
        q = np.asarray(q, dtype=np.float64)
        return np.asarray(0.5 * np.sum(_wavenumbers(q.shape[-1]) ** 2 * q * q, axis=-1))

    def energy(self, q: ArrayLike, p: ArrayLike) -> FloatArray:
        """E = int u_t^2 / 2 + c^2 S / 2 + k S^2 / 4, over the last axis (modes 1..N)."""
        s = self.stretch(q)
        kinetic = 0.25 * np.sum(np.asarray(p, dtype=np.float64) ** 2, axis=-1)
        return np.asarray(kinetic + 0.5 * self.c**2 * s + 0.25 * self.k * s * s)

    def stretch_at_energy(self, energy: ArrayLike) -> FloatArray:
        """S*: the stretch at which all of ``energy`` is potential (the largest S reachable)."""
        e = np.asarray(energy, dtype=np.float64)
        c2 = self.c**2
        if self.k == 0.0:
            return np.asarray(2.0 * e / c2)
        # c^2 S / 2 + k S^2 / 4 = E, written so that it does not cancel for small k E.
        return np.asarray(4.0 * e / (c2 + np.sqrt(c2 * c2 + 4.0 * self.k * e)))

    def nonlinearity(self, q: ArrayLike, p: ArrayLike) -> FloatArray:
        """k S* / c^2: 0 is the linear string; 1 doubles the tension at the largest stretch."""
        return np.asarray(self.k * self.stretch_at_energy(self.energy(q, p)) / self.c**2)


def frequency_ratio(nonlinearity: ArrayLike) -> FloatArray:
    """One mode's angular frequency over its linear one, at nonlinearity eps = k S* / c^2.

    Mode n alone is the Duffing oscillator q'' + w0^2 q + beta q^3 = 0 with w0 = n pi c and
    beta = k (n pi)^4 / 2. From rest at amplitude A, q = A cn(W t | m) with W^2 = w0^2 (1 + eps),
    m = eps / (2 (1 + eps)), since beta A^2 = w0^2 eps; the period is 4 K(m) / W. The ratio
    depends on eps alone, the same for every mode: 1 + 3 eps / 8 for small eps, 1.318 at 1.
    """
    eps = np.asarray(nonlinearity, dtype=np.float64)
    if not np.all(eps >= 0.0):
        raise InvalidProblem("the nonlinearity must be a number >= 0")
    m = eps / (2.0 * (1.0 + eps))
    return np.asarray(math.pi * np.sqrt(1.0 + eps) / (2.0 * ellipk(m)))


def sine_basis(x: ArrayLike, modes: int) -> FloatArray:
    """sin(n pi x) for n = 1..modes at the points x: shape (points, modes)."""
    x = np.asarray(x, dtype=np.float64)
    return np.sin(np.outer(x, _wavenumbers(modes)))


def _wavenumbers(modes: int) -> FloatArray:
    return math.pi * np.arange(1, modes + 1, dtype=np.float64)


@dataclass(frozen=True)
class KirchhoffSolution:
    """Modal amplitudes at the requested times: q, p shaped (times, modes)."""

    string: KirchhoffString
    t: FloatArray
    q: FloatArray
    p: FloatArray

    def at_points(self, x: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(u, u_t) at the points x, each shaped (times, points)."""
        basis = sine_basis(x, self.q.shape[1])
        return self.q @ basis.T, self.p @ basis.T

    def energy(self) -> FloatArray:
        """The energy at each time (constant up to the integration error)."""
        return self.string.energy(self.q, self.p)

    def stretch(self) -> FloatArray:
        """S = int u_x^2 dx at each time."""
        return self.string.stretch(self.q)


def solve_kirchhoff(
    string: KirchhoffString,
    q0: ArrayLike,
    p0: ArrayLike,
    t: ArrayLike,
    rtol: float = DEFAULT_RTOL,
) -> KirchhoffSolution:
    """Integrate the Galerkin system from modal data (q0, p0) at t = 0; report at times ``t``.

    Only the modes with nonzero data are integrated (the others stay zero exactly). The
    absolute tolerance is ``rtol`` times the state's largest modal speed in the energy norm
    (omega_n q_n and p_n, omega_n = n pi c), so that every mode's error is controlled relative
    to the motion's energy, the fast modes' included.

    Args:
        string: c and k.
        q0: Initial sine coefficients of u, mode 1 first.
        p0: Initial sine coefficients of u_t (the same length).
        t: Output times: increasing, the first >= 0.
        rtol: DOP853's relative tolerance (the absolute one follows from it).
    """
    q0, p0, times = _checked(q0, p0, t, rtol)
    modes = q0.size
    q = np.zeros((times.size, modes))
    p = np.zeros((times.size, modes))
    active = np.flatnonzero((q0 != 0.0) | (p0 != 0.0))
    if active.size == 0 or times[-1] == 0.0:
        q[:], p[:] = q0, p0
        return KirchhoffSolution(string, times, q, p)
    k2 = _wavenumbers(modes)[active] ** 2
    omega = string.c * np.sqrt(k2)
    # Errors measured in the energy norm (omega_n q_n, p_n): a fast mode's small q_n weighs
    # omega_n times more in the energy than in u, and each mode's p_n weighs alike.
    speed = float(np.max(np.hypot(omega * q0[active], p0[active])))
    atol = rtol * speed * np.concatenate([1.0 / omega, np.ones(active.size)])
    c2, k, m = string.c**2, string.k, active.size

    def rhs(_: float, y: FloatArray) -> FloatArray:
        qa = y[:m]
        tension = c2 + k * 0.5 * np.dot(k2, qa * qa)
        return np.concatenate([y[m:], -tension * k2 * qa])

    y0 = np.concatenate([q0[active], p0[active]])
    result = solve_ivp(
        rhs, (0.0, float(times[-1])), y0, method="DOP853", t_eval=times, rtol=rtol, atol=atol
    )
    if not result.success:
        raise RuntimeError(f"DOP853 failed: {result.message}")
    q[:, active] = result.y[:m].T
    p[:, active] = result.y[m:].T
    return KirchhoffSolution(string, times, q, p)


def _checked(
    q0: ArrayLike, p0: ArrayLike, t: ArrayLike, rtol: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    q = np.asarray(q0, dtype=np.float64)
    p = np.asarray(p0, dtype=np.float64)
    times = np.asarray(t, dtype=np.float64)
    if q.ndim != 1 or q.shape != p.shape or q.size == 0:
        raise InvalidProblem(f"q0 and p0 must be 1-D of one length, got {q.shape} and {p.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
        raise InvalidProblem("q0 and p0 must be finite")
    increasing = times.size > 0 and times[0] >= 0.0 and np.all(np.diff(times) > 0.0)
    if times.ndim != 1 or not increasing or not np.all(np.isfinite(times)):
        raise InvalidProblem("t must be 1-D, finite, increasing, and start at or after 0")
    if not (math.isfinite(rtol) and rtol > 0.0):
        raise InvalidProblem(f"rtol must be a positive number, got {rtol}")
    return q, p, times


class KirchhoffReference(ExactSolution):
    """The ``string-kirchhoff`` problem's solution: its Galerkin system integrated by DOP853.

    The problem's initial shape lies in ``StringKirchhoff.MODES`` sine modes, which the motion
    never leaves, so the series is complete: ``truncation_error`` is 0, and what remains is the
    integrator's tolerance (``rtol``, relative to the motion's energy). Each call integrates from
    t = 0 to the latest time asked for; ``on_points`` frames do the same per frame (a film of
    this problem is for references and checks, not for serving at a simulator's rate).
    """

    def __init__(self, problem: StringKirchhoff, rtol: float = DEFAULT_RTOL) -> None:
        self.problem = problem
        self.string = KirchhoffString(problem.c, problem.stretch)
        self.q0 = problem.initial_modes()
        self.rtol = max(rtol, DEFAULT_RTOL)
        self.n_modes = int(self.q0.size)
        self.truncation_error = 0.0

    def amplitudes(self, t: ArrayLike) -> FloatArray:
        """q(t) for each time (any order): shape (nt, modes)."""
        times = self.check_times(t)
        if np.any(times < 0.0):
            raise InvalidQuery(f"{self.problem.name}: times must be >= 0")
        order = np.unique(times)
        solved = solve_kirchhoff(self.string, self.q0, np.zeros_like(self.q0), order, self.rtol)
        return solved.q[np.searchsorted(order, times)]

    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        x = self.check_points(points)[:, 0]
        return np.asarray(sine_basis(x, self.n_modes) @ self.amplitudes(t).T)

    def on_points(self, points: ArrayLike, max_bytes: int | None = None) -> PointFrames:
        x = self.check_points(points)[:, 0]
        basis = sine_basis(x, self.n_modes)
        check_budget("the Kirchhoff-Carrier frames' basis", int(basis.nbytes), max_bytes)

        def frame(t: float) -> FloatArray:
            return np.asarray(basis @ self.amplitudes([t])[0])

        return PointFrames(frame, int(basis.nbytes), "dense")
