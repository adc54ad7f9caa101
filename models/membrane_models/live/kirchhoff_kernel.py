"""The nonlinear string's step tension and transition as one compiled loop (numba, optional).

The same arithmetic as ``kirchhoff_tension.tension_newton`` and ``KirchhoffEngine._transition``
for a step with at most one contact row (the haptic loop's probe or grasp): the guess from the
start's stretch and its first two rates, Newton on T with the row's force solved at each T
(one row: F = b / C, a probe's at least 0), then the theta step's coefficients at T. Each
entry is the numpy path's expression evaluated in the same order; the dot products are summed
in another order, so the two agree to rounding (``tests/models/live/test_live_kirchhoff.py``).

Why compiled: a step of the string is about 30 vector operations over 128 modes beyond the
linear rope's (the stretch and its rates, one or two Newton evaluations, the transition's six
coefficients), each a numpy call of about 0.6 us whatever its length: numpy's path costs 2.3
to 3.3 times the linear rope's free step (``benchmarks/kirchhoff_live.py``, its "numpy path").
The kernels make one pass per evaluation over the modes and write the coefficients into the
engine's per-thread workspace (no arrays made per step); a call costs about 1 us of numba's
dispatch, the more arguments the more. Without numba (the ``server`` extra) the engine takes
the numpy path. They compile when the first engine is built (5.7 s on this machine), or load
from numba's on-disk cache (module-level functions: found again by every process; 0.4 s),
never on a step.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["COEFFICIENTS", "CONSTANT_ROWS", "PARAMETERS", "ROW", "compiled_theta_step"]

FloatArray = NDArray[np.float64]

# a workspace's rows (modes on the columns): the transition's coefficients the kernels write
# (qq, qv, vq, vv, zoh_q, zoh_v), then the per-theta constants, then one row that starts with
# the scalars (``PARAMETERS``)
COEFFICIENTS = 6
CONSTANT_ROWS = (
    "kappa2", "d0", "d1", "kept", "from_q", "from_v", "from_force", "relaxed", "n1", "friction",
)  # fmt: skip
# the scalars: c^2, k, theta, alpha, dt, the Newton's settled change and its most iterations
PARAMETERS = ("c2", "k", "theta", "alpha", "dt", "settled", "max_newton")
# a contact row: whether it is held (1.0, a grasp) or not (0.0, a probe), its depth, offset
# and residual, and the basis's scale (``stepper.StepRows``)
ROW = ("held", "depth", "offset", "residual", "scale")


def _theta_step(
    q0: Any, v0: Any, loaded: bool, p: Any, work: Any, contact: bool, shape: Any, row: Any
) -> Any:
    """(T, S0, miss): the step's tension from (q0, v0) under the held modal force ``p``
    (``loaded``: else none) and at most one contact row (``contact``: ``shape`` its modal force
    per unit force, ``row`` its ``ROW``; ``stepper.StepRows``), and the miss
    c^2 + k ((1 - theta) S0 + theta S1) - T of the step at it (contact included); the
    transition's coefficients at it written to the workspace ``work``'s first rows."""
    out, c = work[:COEFFICIENTS], work[COEFFICIENTS:]
    kappa2, d0, d1, kept = c[0], c[1], c[2], c[3]
    from_q, from_v, from_force, relaxed, n1, friction = c[4], c[5], c[6], c[7], c[8], c[9]
    scalars = c[len(CONSTANT_ROWS)]
    c2, k, theta, alpha, dt = scalars[0], scalars[1], scalars[2], scalars[3], scalars[4]
    settled, max_newton = scalars[5], int(scalars[6])
    held = contact and row[0] != 0.0
    n = q0.shape[0]
    s0 = rate = speed = curvature = push = drag = 0.0
    m = np.empty(n)
    for i in range(n):
        kq = kappa2[i] * q0[i]
        s0 += kq * q0[i]
        rate += kq * v0[i]
        speed += kappa2[i] * v0[i] * v0[i]
        curvature += kq * kq
        drag += kq * (friction[i] * v0[i])
        m[i] = from_q[i] * q0[i] + from_v[i] * v0[i]
        if loaded:
            push += kq * p[i]
            m[i] += from_force[i] * p[i]
    s0 *= 0.5
    second = speed - (c2 + k * s0) * curvature + push - drag
    floor = c2 + k * (1.0 - theta) * s0  # T >= floor: S1 >= 0 and k >= 0
    tension = max(c2 + k * (s0 + theta * dt * (rate + 0.5 * dt * second)), floor)
    gain = np.empty(n)
    miss = 0.0
    last = False  # the evaluation after a settled change: its miss and gains are kept
    for _ in range(max_newton + 1):
        z = compliance = 0.0
        for i in range(n):
            gain[i] = kept[i] / (d0[i] + tension * d1[i])
        if contact:
            for i in range(n):
                z += shape[i] * (m[i] * gain[i] - alpha * q0[i])
                compliance += (shape[i] * (from_force[i] * gain[i])) * shape[i]
        force = 0.0
        cc = 0.0
        if contact:
            cc = row[4] * compliance + row[3]
            b = row[4] * z + row[2] + row[1]
            if cc > 0.0 and (held or b > 0.0):
                force = b / cc
        s1 = slope = sw = kgs = 0.0
        for i in range(n):
            u = m[i] * gain[i]
            q1 = u - alpha * q0[i]
            if force != 0.0:
                shaped = shape[i] * (from_force[i] * gain[i])
                q1 -= force * shaped
                u -= force * shaped
                kgs += (kappa2[i] * q1) * shaped
                sw += shape[i] * (u * d1[i] * gain[i])
            kq1 = kappa2[i] * q1
            s1 += kq1 * q1
            slope += kq1 * (u * d1[i] * gain[i])
        miss = c2 + k * ((1.0 - theta) * s0 + theta * 0.5 * s1) - tension
        if last or not np.isfinite(tension):
            break
        rate1 = -slope
        if force != 0.0:
            rate1 -= (-row[4] * sw / cc) * kgs
        change = miss / (1.0 - theta * k * rate1)
        tension = max(tension + change, floor)
        last = abs(change) <= settled * tension
    if not last:  # no settled change: the coefficients at the last tension
        for i in range(n):
            gain[i] = kept[i] / (d0[i] + tension * d1[i])
    for i in range(n):
        g = gain[i]
        vq = -dt * tension * kappa2[i] * g
        vv = (relaxed[i] - tension * n1[i]) * g
        zoh_v = dt * g
        out[0, i] = kept[i] + theta * dt * vq
        out[1, i] = (1.0 - theta) * dt * kept[i] + theta * dt * vv
        out[2, i] = vq
        out[3, i] = vv
        out[4, i] = theta * dt * zoh_v
        out[5, i] = zoh_v
    return tension, s0, miss


Kernel = Callable[..., tuple[float, float, float]]
Stepped = Callable[..., tuple[float, float, FloatArray, FloatArray]]

try:
    import numba
    from numba import types
except ImportError:  # the server extra brings it; without, the engine takes the numpy path
    numba = None  # type: ignore[assignment]
    types = None  # type: ignore[assignment]


def _jit(function: Any, *signature: Any) -> Any:
    """``function`` compiled (for ``signature`` now, else on first use), from numba's on-disk
    cache where it has one: module-level functions only, whose cache is found again by every
    process."""
    jit: Any = numba.njit
    arguments = (signature,) if signature else ()
    try:
        return jit(*arguments, cache=True, nogil=True)(function)
    except RuntimeError:  # no writable cache directory: each process compiles its own
        return jit(*arguments, nogil=True)(function)


_step = _jit(_theta_step) if numba is not None else None


def _free(q0: Any, v0: Any, work: Any) -> Any:
    return _step(q0, v0, False, q0, work, False, q0, q0)


def _loaded(q0: Any, v0: Any, p: Any, work: Any) -> Any:
    return _step(q0, v0, True, p, work, False, q0, q0)


def _pressed(q0: Any, v0: Any, p: Any, work: Any, shape: Any, row: Any) -> Any:
    return _step(q0, v0, True, p, work, True, shape, row)


def _stepped(q0: Any, v0: Any, loaded: bool, p: Any, work: Any) -> Any:
    """A step without contact whole: (T, miss, q, v), q and v by the stepping core's free
    step's expressions on the coefficients, in its order (q = qq q0 + qv v0 + zoh_q p, and so
    v: the same bits)."""
    tension, _, miss = _step(q0, v0, loaded, p, work, False, q0, q0)
    n = q0.shape[0]
    q, v = np.empty(n), np.empty(n)
    for i in range(n):
        a, b = q0[i], v0[i]
        if loaded:
            q[i] = work[0, i] * a + work[1, i] * b + work[4, i] * p[i]
            v[i] = work[2, i] * a + work[3, i] * b + work[5, i] * p[i]
        else:
            q[i] = work[0, i] * a + work[1, i] * b
            v[i] = work[2, i] * a + work[3, i] * b
    return tension, miss, q, v


@functools.cache
def compiled_theta_step() -> tuple[Kernel, Kernel, Kernel, Stepped] | None:
    """The compiled kernels (compiled now, or loaded from numba's cache), None without numba:
    ``free(q0, v0, work)``, ``loaded(q0, v0, p, work)`` and, with one contact row,
    ``pressed(q0, v0, p, work, shape, row)`` (as few arguments as can be: each costs a call
    about 0.3 us of numba's dispatch), and ``stepped(q0, v0, loaded, p, work)``: a step
    without contact whole."""
    if numba is None:
        return None
    one = types.Array(types.float64, 1, "C", readonly=True)
    work = types.Array(types.float64, 2, "C")
    return (
        _jit(_free, one, one, work),
        _jit(_loaded, one, one, one, work),
        _jit(_pressed, one, one, one, work, one, one),
        _jit(_stepped, one, one, types.boolean, one, work),
    )
