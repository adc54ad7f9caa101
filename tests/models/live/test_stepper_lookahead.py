"""``lookahead``: each probe's free displacement at the end of the next step, without taking
it, is what that step itself finds before its contact (bit for bit), under either hold."""

from __future__ import annotations

import math

import pytest

from membrane_models.live import Hold, Load, LookaheadEngine, ModalEngine, Probe
from membrane_models.problems import make_problem

MEMBRANE = make_problem("membrane-forced")
PROBES = [
    Probe((0.5, 0.5), -1e3, 0.05),
    Probe((0.3, 0.6), -1e3, 0.08),
    Probe((1.5, 0.5), 0.0, 0.05),
]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_the_look_ahead_is_the_next_steps_free_displacement(hold: Hold) -> None:
    engine = ModalEngine(MEMBRANE, (12, 12), 1e-3, modes=(16, 16), damping=0.02, hold=hold)
    assert isinstance(engine, LookaheadEngine)
    loads = [Load((0.45, 0.5), -0.3, 0.05)]
    state = engine.start().state
    for k in range(5):  # a moving state, under a load that changes
        state = engine.step(state, [Load((0.45, 0.5), -0.1 * k, 0.05)], frame=False).state
    ahead = engine.lookahead(state, loads, PROBES)
    taken = engine.step(state, loads, PROBES, frame=False).probes  # lifted clear: no contact
    assert [r.force for r in taken[:2]] == [0.0, 0.0]
    assert ahead[:2] == tuple(r.displacement for r in taken[:2])  # the same arithmetic
    assert taken[2].outside and math.isnan(ahead[2])
    moved = engine.lookahead(state, [], PROBES[:1])[0]
    assert abs(moved - ahead[0]) > 1e-6 * abs(ahead[0])  # the held load counts
