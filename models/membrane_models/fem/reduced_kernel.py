"""The reduced plate's step, when the last step's iteration matrix and contact set hold, as one
compiled loop (numba, optional).

``reduced_dynamics.step_reduced`` is a chord iteration: the last step's factored Jacobian is
used for the first iterations, and at each iterate the tools' forces come from the last step's
active set (one product with its kept solution matrix) while that set stays right. A held or
slowly moving tool keeps both for most steps, which then take one to three iterations of about
25 small numpy calls each (about 1 us apiece whatever the size here: r is about 21, the pairs
231, the tools' points a dozen). This module makes those iterations one call: the same
residual, LU solve, contact solution and stopping rule, each sum taken in another order.

It runs up to ``refresh`` chord iterates (8, where the numpy path refreshes the Jacobian after
3: an iterate here costs about 10 us, a fresh Jacobian about 200), then hands on: the numpy
path goes on from its iterate with a fresh Jacobian. Where the set changes, the numpy path
goes on from the kernel's iterate on the same matrix, searching for the set; where a value is
not finite, it takes the step from its start. Both stop at the same tolerance on the step, so
the two agree to Newton's tolerance (``tests/models/fem/test_reduced_kernel.py``).

Without numba (the ``server`` extra brings it) every step takes the numpy path. The kernel
compiles when the first engine is built, or loads from numba's on-disk cache; never on a step.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CONTACT_CHANGED", "CONVERGED", "NOT_FINITE", "REFRESH_DUE", "SCALARS", "Chord",
    "compiled_chord",
]  # fmt: skip

FloatArray = NDArray[np.float64]

# the kernel's status: it solved the step; a value was not finite (the numpy path starts
# afresh); or a refresh fell due or the set changed (the numpy path goes on from its iterate)
CONVERGED, NOT_FINITE, CONTACT_CHANGED, REFRESH_DUE = 0, 1, 2, 3

# the scalars' slots: dt, the relative tolerance, the iterations before a refresh falls due,
# the contact's tolerance, the contact's case (0: no points; 1: the kept set's solution; 2: the
# kept set is empty), and whether the extra rows' acceleration and load are given (1.0) or not
_DT, _TOLERANCE, _REFRESH, _CONTACT_TOLERANCE, _CASE, _ACCELERATION, _LOAD = range(7)
SCALARS = 7


def _chord(
    q0: Any, v0: Any, extra: Any, lagging: Any, packed: Any, pair_diagonal: Any, pairs: Any,
    index: Any, lu: Any, pivots: Any, contact: Any, solution: Any, surface: Any, scalars: Any,
) -> Any:  # fmt: skip
    """(status, q, v, forces, displacement, iteration): ``reduced_dynamics.step_reduced`` on a
    kept matrix and set (module docstring). Converged: ``iteration`` is the iterations taken;
    else q is the iterate the numpy path goes on from, at ``iteration``. ``extra`` holds the
    last step's mean acceleration and the modal load as rows, ``pairs`` the pairs' (first,
    second) as rows, ``contact`` the points' shapes P (p, r), the response J^-1 P' transposed
    (p, r) and the flexibility (p, p) side by side, (p, 2 r + p)."""
    r = q0.shape[0]
    count = pairs.shape[1]
    p = surface.shape[0]
    dt, tolerance, refresh = scalars[_DT], scalars[_TOLERANCE], int(scalars[_REFRESH])
    contact_tolerance, case = scalars[_CONTACT_TOLERANCE], int(scalars[_CASE])
    q, known = np.empty(r), np.empty(r)
    largest_guess = 0.0
    for i in range(r):  # step_reduced's guess and known side, in its order
        ahead = q0[i] + dt * v0[i]
        q[i] = ahead + (0.5 * dt * dt) * extra[0, i] if scalars[_ACCELERATION] else ahead
        known[i] = (2.0 / dt**2) * ahead + lagging[i] * q0[i]
        if scalars[_LOAD]:
            known[i] += extra[1, i]
        largest_guess = max(largest_guess, abs(q[i]))
    bound = tolerance * max(largest_guess, 1e-300)
    start = np.empty(count)
    for n in range(count):
        start[n] = q0[pairs[0, n]] * q0[pairs[1, n]]
    products, f, s = np.empty(count), np.empty(r), np.empty(r)
    forces, free, step = np.zeros(p), np.empty(p), np.empty(r)
    v, displacement = np.empty(r), np.empty(p)
    for iteration in range(1, refresh + 1):
        for n in range(count):
            products[n] = 0.5 * (q[pairs[0, n]] * q[pairs[1, n]] + start[n])
        mean = packed @ products
        for i in range(r):
            s[i] = q0[i] + q[i]
        for i in range(r):
            total = 0.0
            for j in range(r):
                total += (mean[index[i, j]] + pair_diagonal[index[i, j]]) * s[j]
            f[i] = total - known[i]
        _lu_solve(lu, pivots, f)  # f is now the Newton shift
        for i in range(r):
            step[i] = f[i]
        if case != 0:
            for k in range(p):
                total = 0.0
                for j in range(r):
                    total += contact[k, j] * (q[j] - f[j])
                free[k] = total - surface[k]
            if case == 2:
                for k in range(p):
                    if free[k] > 0.0:
                        return CONTACT_CHANGED, q, v, forces, displacement, iteration
            else:
                solved = solution @ free
                lowest_force, lowest_gap, largest = np.inf, np.inf, 0.0
                for k in range(p):
                    forces[k] = solved[k]
                    lowest_force = min(lowest_force, solved[k])
                    largest = max(largest, abs(free[k]))
                for k in range(p, solved.shape[0]):
                    lowest_gap = min(lowest_gap, solved[k])
                if lowest_force < 0.0 or not (
                    lowest_gap >= 0.0 or lowest_gap >= -contact_tolerance * largest
                ):
                    return CONTACT_CHANGED, q, v, forces, displacement, iteration
                for j in range(r):
                    total = 0.0
                    for k in range(p):
                        total += contact[k, r + j] * forces[k]
                    step[j] += total
        change, size = 0.0, 0.0
        for i in range(r):
            q[i] -= step[i]
            change = max(change, abs(step[i]))
            size = max(size, abs(q[i]))
        if not np.isfinite(change):
            return NOT_FINITE, q, v, forces, displacement, iteration
        if change <= bound or change <= tolerance * size:
            for i in range(r):
                v[i] = (q[i] - q0[i]) * (2.0 / dt) - v0[i]
            for k in range(p):
                total = 0.0
                for j in range(r):
                    total += contact[k, j] * q[j]
                flexed = 0.0
                for m in range(p):
                    flexed += contact[k, 2 * r + m] * forces[m]
                displacement[k] = total - flexed
            return CONVERGED, q, v, forces, displacement, iteration
    return REFRESH_DUE, q, v, forces, displacement, refresh + 1


def _lu_solve_numpy(lu: Any, pivots: Any, b: Any) -> None:
    """b <- A^-1 b from LAPACK's getrf of A (0-based pivots, as scipy gives them)."""
    n = b.shape[0]
    for i in range(n):
        j = pivots[i]
        if j != i:
            b[i], b[j] = b[j], b[i]
    for i in range(n):  # L, unit diagonal
        total = b[i]
        for j in range(i):
            total -= lu[i, j] * b[j]
        b[i] = total
    for i in range(n - 1, -1, -1):  # U
        total = b[i]
        for j in range(i + 1, n):
            total -= lu[i, j] * b[j]
        b[i] = total / lu[i, i]


Chord = Callable[..., tuple[int, FloatArray, FloatArray, FloatArray, FloatArray, int]]

try:
    import numba
except ImportError:  # the server extra brings it; without, every step takes the numpy path
    numba = None  # type: ignore[assignment]


def _jit(function: Any, *signature: Any) -> Any:
    """``function`` compiled (for ``signature`` now, else on first use), from numba's on-disk
    cache where it has one."""
    jit: Any = numba.njit
    arguments = (signature,) if signature else ()
    try:
        return jit(*arguments, cache=True, nogil=True)(function)
    except RuntimeError:  # no writable cache directory: each process compiles its own
        return jit(*arguments, nogil=True)(function)


# ``_chord`` calls it by this name: compiled, for numba to compile the call
_lu_solve = _lu_solve_numpy if numba is None else _jit(_lu_solve_numpy)


@functools.cache
def compiled_chord() -> Chord | None:
    """The compiled chord iteration (``_chord``, compiled now or loaded from numba's cache),
    None without numba. Its inputs are declared read-only (writable arrays are taken too), the
    products' matrices C-ordered (BLAS), the rest in any order: no call compiles anew."""
    if numba is None:
        return None
    types: Any = numba.types

    def array(dtype: Any, dims: int, layout: str = "A") -> Any:
        return types.Array(dtype, dims, layout, readonly=True)

    f64, index = types.float64, types.intp
    signature = (
        array(f64, 1), array(f64, 1), array(f64, 2), array(f64, 1),  # q0, v0, extra, lagging
        array(f64, 2, "C"), array(f64, 1), array(index, 2), array(index, 2),  # the pairs'
        array(f64, 2), array(types.int32, 1),  # the LU and its pivots
        array(f64, 2), array(f64, 2, "C"), array(f64, 1),  # the contact's
        array(f64, 1),  # scalars
    )  # fmt: skip
    return _jit(_chord, *signature)
