"""Many sessions' load steps as one operation (``ModalStepper.step_loads``, the free-step kernel):
the same bits as the transition's numpy expressions, as a lone step and at any batch width; a
refused state costs only itself; an engine whose step solves for its end steps one by one."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from membrane_models.live import BatchedEngine, InvalidLoad, LiveError, Load, ModalEngine
from membrane_models.live.free_step import COMPILED, FreeStepKernel, stacked_transition
from membrane_models.live.kirchhoff import build_kirchhoff_engine
from membrane_models.live.stepper import ModalState
from membrane_models.live.transition import transition
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]
MEMBRANE = make_problem("membrane-forced")


def _expressions(
    tr_fields: dict[str, FloatArray], q0: FloatArray, v0: FloatArray, p1: FloatArray,
    p0: FloatArray, hold: str, loaded: bool,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The step as the stepping core wrote it before the kernel: numpy, left to right."""
    t = tr_fields
    q = t["qq"] * q0
    q += t["qv"] * v0
    v = t["vq"] * q0
    v += t["vv"] * v0
    if hold == "foh":
        q += t["foh0_q"] * p0 + t["foh1_q"] * p1
        v += t["foh0_v"] * p0 + t["foh1_v"] * p1
    elif loaded:
        q += t["zoh_q"] * p1
        v += t["zoh_v"] * p1
    return q, v


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("compiled", [True, False])
def test_the_kernel_gives_the_numpy_expressions_bits(hold: str, compiled: bool) -> None:
    """Separable loads (one, two), a modal force given, and no load: the expressions' bits."""
    if compiled and not COMPILED:
        pytest.skip("numba is not installed (the server extra brings it)")
    kx, ky = 20, 15
    omega = np.linspace(1.0, 900.0, kx * ky).reshape(kx, ky)
    tr, block = stacked_transition(transition(omega, 0.02, 1e-3))
    kernel = FreeStepKernel(block, hold, compiled=compiled)  # type: ignore[arg-type]
    assert kernel.compiled is compiled
    fields = {name: getattr(tr, name).reshape(-1) for name in tr.__dataclass_fields__}
    rng = np.random.default_rng(1)
    q0, v0, p0 = (rng.standard_normal(kx * ky) for _ in range(3))
    xs, ys = rng.standard_normal((2, kx)), rng.standard_normal((2, ky))
    forces = [0.7, -1.3]
    for count in (1, 2):
        p1 = forces[0] * (xs[0][:, None] * ys[0][None, :])
        if count == 2:
            p1 += forces[1] * (xs[1][:, None] * ys[1][None, :])
        factors = [(xs[m], ys[m]) for m in range(count)]
        free = kernel.separable(q0, v0, p0, factors, forces[:count])
        want = _expressions(fields, q0, v0, p1.reshape(-1), p0, hold, True)
        assert free.p1.tobytes() == p1.reshape(-1).tobytes()
        assert free.q.tobytes() == want[0].tobytes() and free.v.tobytes() == want[1].tobytes()
        given = kernel.given(q0, v0, p0, p1.reshape(-1))
        assert given.q.tobytes() == want[0].tobytes() and given.v.tobytes() == want[1].tobytes()
        assert np.isclose(free.total, want[0].sum() + want[1].sum(), rtol=1e-12)
    idle = kernel.given(q0, v0, p0, None)
    want = _expressions(fields, q0, v0, np.zeros(kx * ky), p0, hold, False)
    assert idle.q.tobytes() == want[0].tobytes() and idle.v.tobytes() == want[1].tobytes()


def test_the_comparison_would_catch_one_ulp() -> None:
    """Its power: the bitwise comparison above tells a last-bit difference."""
    q = np.random.default_rng(2).standard_normal(50)
    assert np.nextafter(q, np.inf).tobytes() != q.tobytes()


def _engine(hold: str = "zoh") -> ModalEngine:
    return ModalEngine(MEMBRANE, 12, 0.002, damping=0.01, hold=hold)  # type: ignore[arg-type]


def _loads(index: int, k: int) -> list[Load]:
    at = (0.15 + 0.05 * (index % 13), 0.3 + 0.02 * (index % 7))
    return [Load(at, -0.4 * (1 + (k + index) % 3), 0.06)] * (1 + index % 2)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_a_batch_of_64_is_64_lone_steps_bit_for_bit(hold: str) -> None:
    engine = _engine(hold)
    assert isinstance(engine, BatchedEngine)
    alone = [engine.start().state for _ in range(64)]
    together = list(alone)
    for k in range(6):
        frames = [(i + k) % 4 == 0 for i in range(64)]
        alone_results = [engine.step(s, _loads(i, k), frame=frames[i]) for i, s in enumerate(alone)]
        batch = engine.step_loads(together, [_loads(i, k) for i in range(64)], frames)
        for one, many in zip(alone_results, batch, strict=True):
            assert not isinstance(many, LiveError)
            assert one.state.q.tobytes() == many.state.q.tobytes()
            assert one.state.v.tobytes() == many.state.v.tobytes()
            assert (one.frame is None) == (many.frame is None)
            if one.frame is not None and many.frame is not None:
                assert one.frame.tobytes() == many.frame.tobytes()
        alone = [r.state for r in alone_results]
        together = [r.state for r in batch if not isinstance(r, LiveError)]
    assert np.abs(engine.frame(together[5])).max() > 1e-5  # the loads moved the tissue
    # each state owns its arrays: none keeps another's alive
    assert all(s.q.base is None or s.q.base.size == s.q.size for s in together)


def test_a_lone_load_step_is_the_transition_applied() -> None:
    """Against the transition itself (independent of the kernel): q1 = qq q0 + qv v0 + zoh_q p."""
    engine = _engine()
    state = engine.step(engine.start().state, _loads(0, 0), frame=False).state
    loads = _loads(0, 1)
    after = engine.step(state, loads, frame=False).state
    tr = engine.transition
    print_ = engine.basis.footprints(loads, (), engine.budget)[0]
    p = loads[0].force * engine.basis.modal_force(print_[0])
    want = tr.qq * state.q + tr.qv * state.v + tr.zoh_q * p
    assert np.allclose(after.q, want, rtol=1e-14, atol=1e-18)
    assert not np.allclose(after.q, tr.qq * state.q + tr.qv * state.v, rtol=1e-6, atol=0)


def test_a_refused_state_in_a_batch_costs_only_itself() -> None:
    engine = _engine()
    states = [engine.start().state for _ in range(3)]
    bad = [Load((0.5, 0.5), float("nan"), 0.06)]
    results = engine.step_loads(states, [_loads(0, 0), bad, _loads(2, 0)], [True, True, False])
    assert isinstance(results[1], InvalidLoad)
    first, last = results[0], results[2]
    assert isinstance(first.state, ModalState) and first.state.step == 1  # type: ignore[union-attr]
    assert isinstance(last.state, ModalState) and last.frame is None  # type: ignore[union-attr]
    with pytest.raises(InvalidLoad):
        engine.step(states[1], bad)


def test_an_engine_solving_for_its_step_steps_its_batch_one_by_one() -> None:
    """The nonlinear string's transition depends on the step's end: its batch is its steps."""
    engine = build_kirchhoff_engine(make_problem("string-kirchhoff"), (65,), 1e-3, {})
    states = [engine.start().state for _ in range(3)]
    loads = [[Load((0.3 + 0.1 * i,), -2.0, 0.05)] for i in range(3)]
    batch = engine.step_loads(states, loads, [True] * 3)
    for state, given, many in zip(states, loads, batch, strict=True):
        one = engine.step(state, given)
        assert not isinstance(many, LiveError)
        assert one.state.q.tobytes() == many.state.q.tobytes()
