"""The exact one-step transition of damped modal oscillators, per mode a 2 x 2 matrix.

Each mode obeys q'' + 2 zeta w q' + w^2 q = p(t). Over a step of length dt, with x = w dt,

    [q, v](t + dt) = Phi [q, v](t) + (input terms),

exact whatever dt: zero-order hold (p constant over the step) adds G p; first-order hold (p
linear from p0 to p1) adds (G - E / dt) p0 + (E / dt) p1, with G = int_0^dt exp(A s) b ds and
E = int_0^dt (dt - s) exp(A s) b ds (Van Loan's block exponential gives both).

Everything is written in the dimensionless x, so that the entries stay O(1) for any w and dt:
Phi = [[f11, f12 / w], [w f21, f22]], G = [gq / w^2, gv / w], E = [eq / w^3, ev / w^2].
Undamped (the study's equation, the default) these are closed forms: f = [[cos x, sin x],
[-sin x, cos x]], gq = ev = 2 sin^2(x / 2) (not 1 - cos x, which cancels), gv = sin x, and
eq = x - sin x, by its series below x = 0.2 (where the difference cancels). Damped, they come
from the exponential of x [[0, 1, 0, 0], [-1, -2 zeta, 1, 0], [0, 0, 0, 1], [0, 0, 0, 0]],
batched over the modes (``_expm``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Transition", "transition"]

FloatArray = NDArray[np.float64]

_SERIES_BELOW = 0.2  # x - sin x by its series below this (x^15 / 17! ~ 9e-26 at 0.2)
_SERIES_TERMS = 7


@dataclass(frozen=True)
class Transition:
    """Per-mode coefficients of one step (arrays of the modes' shape).

    q1 = qq q0 + qv v0 + (input), v1 = vq q0 + vv v0 + (input), where the input is
    zoh_q p, zoh_v p (zero-order hold) or foh0_q p0 + foh1_q p1 (first-order hold), and so on.
    """

    qq: FloatArray
    qv: FloatArray
    vq: FloatArray
    vv: FloatArray
    zoh_q: FloatArray
    zoh_v: FloatArray
    foh0_q: FloatArray
    foh0_v: FloatArray
    foh1_q: FloatArray
    foh1_v: FloatArray


def transition(omega: FloatArray, zeta: float | FloatArray, dt: float) -> Transition:
    """The step's coefficients for angular frequencies ``omega`` (> 0, any shape) and damping
    ratios ``zeta`` (one for every mode, or one per mode: Rayleigh damping's)."""
    w = np.asarray(omega, dtype=np.float64)
    x = w * dt
    if np.ndim(zeta) == 0:
        ratio = float(zeta)
        parts = _undamped(x) if ratio == 0.0 else _damped(x, ratio)
    else:
        parts = _per_mode(x, np.broadcast_to(np.asarray(zeta, dtype=np.float64), x.shape))
    f11, f12, f21, f22, gq, gv, eq, ev = parts
    zoh_q, zoh_v = gq / w**2, gv / w
    ramp_q, ramp_v = eq / (w**2 * x), ev / (w * x)  # E / dt
    return Transition(
        qq=f11,
        qv=f12 / w,
        vq=f21 * w,
        vv=f22,
        zoh_q=zoh_q,
        zoh_v=zoh_v,
        foh0_q=zoh_q - ramp_q,
        foh0_v=zoh_v - ramp_v,
        foh1_q=ramp_q,
        foh1_v=ramp_v,
    )


def _undamped(x: FloatArray) -> tuple[FloatArray, ...]:
    c, s = np.cos(x), np.sin(x)
    half = 2.0 * np.sin(0.5 * x) ** 2
    return c, s, -s, c, half, s, _x_minus_sin(x), half


def _x_minus_sin(x: FloatArray) -> FloatArray:
    """x - sin x without cancellation: x^3 sum_k (-1)^k x^(2k) / (2k + 3)! for small x."""
    small = np.abs(x) < _SERIES_BELOW
    out = x - np.sin(x)
    if np.any(small):
        xs = x[small]
        series = np.zeros_like(xs)
        for k in reversed(range(_SERIES_TERMS)):
            series = series * xs**2 + (-1.0) ** k / math.factorial(2 * k + 3)
        out[small] = xs**3 * series
    return out


def _per_mode(x: FloatArray, zeta: FloatArray) -> tuple[FloatArray, ...]:
    """Each mode with its own ratio: the closed forms where it is 0, the exponential elsewhere."""
    parts = [np.array(p, dtype=np.float64) for p in _undamped(x)]
    damped = zeta > 0.0
    if damped.any():
        for part, values in zip(parts, _damped(x[damped], zeta[damped]), strict=True):
            part[damped] = values
    return tuple(parts)


def _damped(x: FloatArray, zeta: float | FloatArray) -> tuple[FloatArray, ...]:
    """Van Loan's block exponential of the dimensionless system, batched over the modes."""
    flat = x.reshape(-1)
    if np.ndim(zeta) == 0:
        generator = np.zeros((4, 4))
        generator[0, 1] = 1.0
        generator[1, 0], generator[1, 1], generator[1, 2] = -1.0, -2.0 * float(zeta), 1.0
        generator[2, 3] = 1.0
        blocks = _expm(flat[:, None, None] * generator[None, :, :])
    else:
        generators = np.zeros((flat.size, 4, 4))
        generators[:, 0, 1] = 1.0
        generators[:, 1, 0], generators[:, 1, 2] = -1.0, 1.0
        generators[:, 1, 1] = -2.0 * np.asarray(zeta).reshape(-1)
        generators[:, 2, 3] = 1.0
        blocks = _expm(flat[:, None, None] * generators)
    parts = (
        blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 0], blocks[:, 1, 1],
        blocks[:, 0, 2], blocks[:, 1, 2], blocks[:, 0, 3], blocks[:, 1, 3],
    )  # fmt: skip
    return tuple(np.ascontiguousarray(p).reshape(x.shape) for p in parts)


# Taylor degree for exp(M) once M is scaled to a 1-norm of at most 1: the remainder is below
# 1 / 19! ~ 8e-18 of exp(1), under the rounding of the result.
_TAYLOR_DEGREE = 18


def _expm(matrices: FloatArray) -> FloatArray:
    """exp of a batch of small matrices by scaling and squaring a Taylor polynomial, in numpy.

    scipy.linalg.expm gives the same to rounding, but a batched call holds the GIL throughout
    (measured: 200 ms for a 98 x 98 mode box), and so does each of its chunked calls: a scene
    built for a reload would stall the server's serving thread behind it. Batched matmul
    releases the GIL, and grouping the matrices by their number of squarings keeps a small
    step's modes from being squared as often as the stiffest one's.
    """
    norms = np.abs(matrices).sum(axis=-2).max(axis=-1)  # the 1-norm of each
    squarings = np.ceil(np.log2(np.maximum(norms, 1.0))).astype(np.int64)
    identity = np.eye(matrices.shape[-1])
    out = np.empty_like(matrices)
    for count in np.unique(squarings):
        chosen = squarings == count
        scaled = matrices[chosen] / 2.0 ** int(count)
        power: FloatArray = np.broadcast_to(identity, scaled.shape)  # read, never written
        for k in range(_TAYLOR_DEGREE, 0, -1):  # Horner: I + M/k (I + M/(k+1) (...))
            power = identity + np.matmul(scaled, power) / k
        for _ in range(int(count)):
            power = np.matmul(power, power)
        out[chosen] = power
    return out
