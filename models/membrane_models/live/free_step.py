"""The free step (no contact) of a session's modes under its loads: the transition applied in one
pass over the mode box.

A session's q, v at the end of a step from its q0, v0 under its loads' modal force p1
(``transition``'s coefficients; zero-order hold, or first-order hold from the last step's p0):

    q = qq q0 + qv v0 + zoh_q p1                      (zoh, loaded; no input term unloaded)
    q = qq q0 + qv v0 + (foh0_q p0 + foh1_q p1)       (foh)

and v alike, with p1 = F_1 s_1 + F_2 s_2 + ... the loads' forces on their footprints' modal
forces. On the sine basis s is an outer product of per-axis factors (``ModalBasis.modal_factors``)
and p1 is built in the same pass. Every entry is computed by the same operations in the same
order as numpy's expressions above, evaluated left to right, so a step gives the same bits here,
in numpy (``compiled=False``, the reference the compiled loop is tested against), alone or among
many sessions' steps.

Why a compiled loop (numba, in the ``server`` extra): a 60 x 60 mode box is 29 KiB an array, and
numpy's expressions make a pass and a temporary per operation, about twenty passes a step; one
pass that reads q0 and v0 and writes q, v and p1 costs about half as much or less
(``benchmarks/batched_steps.py --kernel``: 18-24 us a session against 42-60 with numpy). Stepping
many sessions as one wide (sessions x modes) numpy array gains little over numpy per session
(41-46 us), so a batch is each session's pass, one after the other. Without numba the same
expressions run in numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.interface import Hold
from membrane_models.live.transition import Transition

__all__ = ["COMPILED", "FreeStep", "FreeStepKernel", "stacked_transition"]

FloatArray = NDArray[np.float64]

# Rows of the coefficients' block, in the order of ``Transition``'s fields.
_FIELDS = tuple(Transition.__dataclass_fields__)
QQ, QV, VQ, VV, ZOH_Q, ZOH_V, FOH0_Q, FOH0_V, FOH1_Q, FOH1_V = range(len(_FIELDS))
_ONE = np.ones(1)
_ONE.setflags(write=False)


def stacked_transition(tr: Transition) -> tuple[Transition, FloatArray]:
    """``tr`` with its coefficients as rows of one read-only block (fields, modes), and the
    block flattened to (fields, modes): the kernel reads the block, everything else the fields
    (views of it: no second copy)."""
    block = np.stack([np.asarray(getattr(tr, name), dtype=np.float64) for name in _FIELDS])
    block.setflags(write=False)
    return Transition(*block), block.reshape(len(_FIELDS), -1)


class FreeStep(NamedTuple):
    """A free step's end: q, v and the loads' modal force p1 (flat, over the mode box), and
    sum(q) + sum(v), finite exactly when every entry is (or the entries near 1e308)."""

    q: FloatArray
    v: FloatArray
    p1: FloatArray
    total: float


try:
    import numba
except ImportError:  # the server extra brings it; without, numpy runs the same expressions
    numba = None  # type: ignore[assignment]


def _jit(function: Any) -> Any:
    """``function`` compiled (on first use, then from the on-disk cache: module-level functions
    only, so that the cache's key is the same in every process)."""
    try:
        return numba.njit(cache=True, nogil=True)(function)
    except RuntimeError:  # no writable cache directory: each process compiles its own
        return numba.njit(nogil=True)(function)


def _advance(c: Any, q0: Any, v0: Any, p0: Any, p1: Any, mode: int, q: Any, v: Any) -> float:
    """q, v (written into the arrays given) and sum(q) + sum(v); ``mode`` 0: no load (zoh),
    1: zoh, 2: foh."""
    n = q0.shape[0]
    total_q, total_v = 0.0, 0.0
    for k in range(n):
        a, b = q0[k], v0[k]
        if mode == 2:
            r, p = p0[k], p1[k]
            qk = c[QQ, k] * a + c[QV, k] * b + (c[FOH0_Q, k] * r + c[FOH1_Q, k] * p)
            vk = c[VQ, k] * a + c[VV, k] * b + (c[FOH0_V, k] * r + c[FOH1_V, k] * p)
        elif mode == 1:
            p = p1[k]
            qk = c[QQ, k] * a + c[QV, k] * b + c[ZOH_Q, k] * p
            vk = c[VQ, k] * a + c[VV, k] * b + c[ZOH_V, k] * p
        else:
            qk = c[QQ, k] * a + c[QV, k] * b
            vk = c[VQ, k] * a + c[VV, k] * b
        q[k], v[k] = qk, vk
        total_q += qk
        total_v += vk
    return total_q + total_v


def _loaded(
    c: Any, q0: Any, v0: Any, p0: Any, xs: Any, ys: Any, forces: Any, foh: bool,
    q: Any, v: Any, p1: Any,
) -> float:  # fmt: skip
    """p1 = F_1 x_1 (x) y_1 + F_2 x_2 (x) y_2 + ... (flat, x-major), then the step: q, v and p1
    written into the arrays given, and sum(q) + sum(v) returned."""
    kx, ky = xs.shape[1], ys.shape[1]
    for i in range(kx):
        for j in range(ky):
            p = forces[0] * (xs[0, i] * ys[0, j])
            for m in range(1, forces.shape[0]):
                p += forces[m] * (xs[m, i] * ys[m, j])
            p1[i * ky + j] = p
    return _advance_compiled(c, q0, v0, p0, p1, 2 if foh else 1, q, v)


_advance_compiled = _jit(_advance) if numba is not None else None
_KERNELS = (_jit(_loaded), _advance_compiled) if numba is not None else None
COMPILED = _KERNELS is not None  # whether steps run the compiled loops


def _read_only(array: FloatArray) -> FloatArray:
    """The array as a read-only one (the compiled loops are typed for read-only inputs)."""
    if array.flags.writeable:
        array = array.view()
        array.flags.writeable = False
    return array


def _rows(factors: list[FloatArray]) -> FloatArray:
    """Factors as the rows of a fresh (writable, C-contiguous) array, as the loop is typed."""
    if len(factors) == 1:
        return factors[0][None, :].copy()
    return np.stack(factors)


class FreeStepKernel:
    """The free step over one engine's transition (flat arrays over the mode box in, fresh
    ones out).

    Args:
        block: the engine's per-mode coefficients as ``stacked_transition`` gives them.
        hold: "zoh" or "foh".
        compiled: use the compiled loops (default: when numba is installed); False runs numpy.
    """

    def __init__(self, block: FloatArray, hold: Hold, compiled: bool | None = None) -> None:
        self.hold = hold
        self._block = block
        self._zeros = np.zeros(block.shape[1])
        self._zeros.setflags(write=False)
        self.compiled = COMPILED if compiled is None else compiled and COMPILED
        if self.compiled:
            self._warm_up()  # compile (or load the compiled loops) now, not on a session's step

    def separable(
        self,
        q0: FloatArray,
        v0: FloatArray,
        p0: FloatArray,
        factors: Sequence[tuple[FloatArray, FloatArray]],
        forces: Sequence[float],
    ) -> FreeStep:
        """The step under loads whose modal forces are outer products s_m = x_m (x) y_m
        (``factors``, each cut to the mode box) with forces F_m: p1 = F_1 s_1 + F_2 s_2 + ...
        ``p0``: the last step's p1 (read under "foh")."""
        if not factors:
            return self.given(q0, v0, p0, None)
        if any(x.shape[0] * y.shape[0] != q0.shape[0] for x, y in factors):
            raise AssertionError("a load's factors do not span the mode box")  # the loop's bounds
        if not self.compiled:
            p1 = forces[0] * np.multiply.outer(*factors[0]).reshape(-1)
            for (x, y), force in zip(factors[1:], forces[1:], strict=True):
                p1 += force * np.multiply.outer(x, y).reshape(-1)
            return self._numpy(q0, v0, p0, p1, True)
        assert _KERNELS is not None
        xs, ys = _rows([x for x, _ in factors]), _rows([y for _, y in factors])
        foh = self.hold == "foh"
        previous = _read_only(p0) if foh else self._zeros
        n = q0.shape[0]
        q, v, p1 = np.empty(n), np.empty(n), np.empty(n)  # numpy's arrays: see ``_advance``
        total = _KERNELS[0](
            self._block, _read_only(q0), _read_only(v0), previous, xs, ys,
            np.array(forces, dtype=np.float64), foh, q, v, p1,
        )  # fmt: skip
        return FreeStep(q, v, p1, total)

    def given(
        self, q0: FloatArray, v0: FloatArray, p0: FloatArray, p1: FloatArray | None
    ) -> FreeStep:
        """The step under the loads' modal force ``p1`` (None: no load)."""
        force = self._zeros if p1 is None else p1
        if not self.compiled:
            return self._numpy(q0, v0, p0, force, p1 is not None)
        return self._advance(q0, v0, p0, _read_only(force), p1 is not None)

    def _advance(
        self, q0: FloatArray, v0: FloatArray, p0: FloatArray, p1: FloatArray, loaded: bool
    ) -> FreeStep:
        assert _KERNELS is not None
        mode = 2 if self.hold == "foh" else int(loaded)
        previous = _read_only(p0) if mode == 2 else self._zeros
        # The outputs are numpy's arrays, passed in: an array the compiled loop allocates and
        # returns costs about 1.2 us more to make and hand back (2.2-2.5 us against 1.1).
        n = q0.shape[0]
        q, v = np.empty(n), np.empty(n)
        total = _KERNELS[1](self._block, _read_only(q0), _read_only(v0), previous, p1, mode, q, v)
        return FreeStep(q, v, p1, total)

    def _numpy(
        self, q0: FloatArray, v0: FloatArray, p0: FloatArray, p1: FloatArray, loaded: bool
    ) -> FreeStep:
        c = self._block
        q = c[QQ] * q0
        q += c[QV] * v0
        v = c[VQ] * q0
        v += c[VV] * v0
        if self.hold == "foh":
            q += c[FOH0_Q] * p0 + c[FOH1_Q] * p1
            v += c[FOH0_V] * p0 + c[FOH1_V] * p1
        elif loaded:
            q += c[ZOH_Q] * p1
            v += c[ZOH_V] * p1
        return FreeStep(q, v, p1, float(q.sum()) + float(v.sum()))

    def _warm_up(self) -> None:
        zero = self._zeros
        self.given(zero, zero, zero, None)
        self.separable(zero, zero, zero, [(zero, _ONE)], [0.0])


def one_factor() -> FloatArray:
    """The second factor of a string's modal force (its box has one axis): s = x (x) [1]."""
    return _ONE
