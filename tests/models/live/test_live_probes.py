"""Probes {at, depth, radius}: exact unilateral contact, convergence, extremes and bad input."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from membrane_models.live import InvalidProbe, Load, ModalEngine, ModalState, Probe
from membrane_models.live.inputs import MAX_PROBES
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]
STRING = make_problem("string-forced")
MEMBRANE = make_problem("membrane-forced")


def _pressed(engine: ModalEngine, probes: list[Any], steps: int) -> tuple[ModalState, Any]:
    state = engine.start().state
    for _ in range(steps):
        result = engine.step(state, [], probes, frame=False)
        state = result.state
    return state, result


def test_one_probe_holds_the_tissue_at_its_face_and_only_pushes() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.002)
    state = engine.start().state
    contacts = releases = 0
    for k in range(200):  # pressing in, then pulling away faster than the tissue follows
        depth = 1e-4 * max(0.0, math.sin(math.pi * k / 100))
        reading = (result := engine.step(state, [], [Probe((0.4, 0.55), depth, 0.05)])).probes[0]
        state = result.state
        assert reading.force >= 0.0 and reading.gap >= 0.0
        if reading.in_contact:
            contacts += 1
            assert reading.displacement == pytest.approx(-depth, rel=1e-10, abs=1e-18)
            assert reading.gap == 0.0
        else:
            releases += 1
            assert reading.force == 0.0
            assert reading.gap == pytest.approx(-(reading.displacement + depth), abs=1e-18)
    assert contacts > 20 and releases > 5


def test_contact_force_is_what_a_load_of_that_force_would_do() -> None:
    """The probe's force, applied as a load on its footprint, leaves the tissue at the face."""
    engine = ModalEngine(MEMBRANE, 20, 0.003)
    start = engine.start().state
    pressed = engine.step(start, [], [Probe((0.3, 0.7), 2e-5, 0.08)])
    force = pressed.probes[0].force
    assert force > 0.0
    # a zero-depth probe is not touched by tissue pushed down: it reads the displacement
    loaded = engine.step(start, [Load((0.3, 0.7), -force, 0.08)], [Probe((0.3, 0.7), 0.0, 0.08)])
    assert loaded.probes[0].force == 0.0
    assert loaded.probes[0].displacement == pytest.approx(-2e-5, rel=1e-10)
    np.testing.assert_allclose(loaded.state.q, pressed.state.q, rtol=0, atol=1e-15)
    assert loaded.frame is not None and pressed.frame is not None
    np.testing.assert_allclose(loaded.frame, pressed.frame, rtol=0, atol=1e-15)


def _force_history(modes: int, corrected: bool) -> FloatArray:
    """A probe pressed slowly (cosine ramp to 1e-4 over 0.3 s, held), dt = 2 ms, 300 steps."""
    engine = ModalEngine(
        MEMBRANE, 20, 0.002, modes=modes, step_limit=None, static_correction=corrected
    )
    state = engine.start().state
    forces = []
    for k in range(1, 301):
        t = min(k * 0.002, 0.3)
        depth = 1e-4 * 0.5 * (1.0 - math.cos(math.pi * t / 0.3))
        result = engine.step(state, [], [Probe((0.35, 0.55), depth, 0.05)], frame=False)
        state = result.state
        forces.append(result.probes[0].force)
    return np.array(forces)


def test_probe_force_converges_with_modes_only_with_the_static_correction() -> None:
    reference = _force_history(100, True)

    def error(history: FloatArray) -> float:
        return float(np.linalg.norm(history - reference) / np.linalg.norm(reference))

    with_correction = [error(_force_history(m, True)) for m in (2, 4, 8, 16)]
    without = [error(_force_history(m, False)) for m in (2, 4, 8, 16)]
    assert with_correction == sorted(with_correction, reverse=True)  # converging
    assert with_correction[0] < 0.05 and with_correction[-1] < 1e-3
    assert without[0] > 0.5 and without[2] > 0.02  # far too stiff without it
    for a, b in zip(with_correction[:3], without[:3], strict=True):
        assert a < b / 4


def test_depth_zero_at_rest_touches_without_force() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    reading = engine.step(engine.start().state, [], [Probe((0.5, 0.5), 0.0, 0.05)]).probes[0]
    assert (reading.force, reading.gap, reading.in_contact) == (0.0, 0.0, False)
    assert reading.compliance > 0.0


def test_a_huge_depth_is_linear_and_finite() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    start = engine.start().state
    small = engine.step(start, [], [Probe((0.5, 0.5), 1e-4, 0.05)])
    huge = engine.step(start, [], [Probe((0.5, 0.5), 1e3, 0.05)])
    assert huge.probes[0].force == pytest.approx(1e7 * small.probes[0].force, rel=1e-10)
    assert huge.frame is not None and np.all(np.isfinite(huge.frame))


BAD_PROBES: list[tuple[Any, str]] = [
    (Probe((0.5, 0.5), -2e3, 0.05), r"depth must be in \[-1000, 1000\], got -2000"),
    (Probe((0.5, 0.5), math.nan, 0.05), "finite"),
    (Probe((0.5, 0.5), math.inf, 0.05), "finite"),
    (Probe((math.inf, 0.5), 0.0, 0.05), "finite"),
    (Probe((0.5, 0.5), 1e-5, 0.0), "logarithmically singular"),
    (Probe((0.5, 0.5), 1e-5, 1e-3), "smallest"),
    (Probe((0.5, 0.5), 2e3, 0.05), r"depth must be in \[-1000, 1000\], got 2000"),
    (Probe((0.5,), 1e-5, 0.05), "2 coordinates"),
    ("probe", "must be a Probe, got str"),
    ({"at": [0.5, 0.5], "depth": 1e-5, "radius": 0.05}, "must be a Probe, got dict"),  # a wire map
]


@pytest.mark.parametrize(("probe", "message"), BAD_PROBES)
def test_bad_probes_raise_and_leave_the_state_intact(probe: Any, message: str) -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.step(engine.start().state, [], [Probe((0.4, 0.4), 1e-5, 0.05)]).state
    q, v = state.q.copy(), state.v.copy()
    with pytest.raises(InvalidProbe, match=message):
        engine.step(state, [Load((0.2, 0.2), 1.0, 0.1)], [Probe((0.6, 0.6), 1e-5, 0.05), probe])
    assert np.array_equal(state.q, q) and np.array_equal(state.v, v) and state.step == 1
    assert state.applied and state.applied[0][1] < 0.0  # still the probe's force from step 1


def test_more_than_eight_probes_are_refused() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    with pytest.raises(InvalidProbe, match=f"at most {MAX_PROBES}"):
        engine.step(engine.start().state, [], [Probe((0.5, 0.5), 0.0, 0.05)] * (MAX_PROBES + 1))


def test_a_probe_outside_the_domain_touches_nothing() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    start = engine.start().state
    load = [Load((0.5, 0.5), 0.2, 0.05)]
    alone = engine.step(start, load)
    with_probe = engine.step(start, load, [Probe((1.3, 0.5), 1.0, 0.05)])
    reading = with_probe.probes[0]
    assert reading.outside and not reading.in_contact and reading.force == 0.0
    assert math.isnan(reading.displacement) and math.isnan(reading.gap)
    assert alone.frame is not None and with_probe.frame is not None
    np.testing.assert_array_equal(alone.frame, with_probe.frame)


def test_a_probe_on_a_clamped_edge_of_the_membrane_presses_half_a_footprint() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    start = engine.start().state
    edge = engine.step(start, [], [Probe((0.0, 0.5), 1e-5, 0.05)]).probes[0]
    inside = engine.step(start, [], [Probe((0.5, 0.5), 1e-5, 0.05)]).probes[0]
    assert edge.in_contact and math.isfinite(edge.force)
    assert edge.displacement == pytest.approx(-1e-5, rel=1e-10)
    corner = engine.step(start, [], [Probe((1.0, 1.0), 1e-5, 0.05)]).probes[0]
    assert corner.in_contact and corner.compliance > 0.0
    # held until static (damped), the clamp stiffens what is left under the tip
    static = ModalEngine(MEMBRANE, 20, 0.05, damping=0.7)
    forces = []
    for at in ((0.5, 0.5), (0.0, 0.5), (1.0, 1.0)):
        _, result = _pressed(static, [Probe(at, 1e-5, 0.05)], 200)
        forces.append(result.probes[0].force)
    assert forces[0] < forces[1] < forces[2]
    assert inside.compliance > 0.0


def test_a_point_probe_on_the_strings_clamped_end() -> None:
    engine = ModalEngine(STRING, 100, 0.001)
    start = engine.start().state
    touching = engine.step(start, [], [Probe((0.0,), 0.0, 0.0)]).probes[0]
    assert touching.force == 0.0 and touching.compliance == 0.0
    with pytest.raises(InvalidProbe, match="cannot move"):
        engine.step(start, [], [Probe((1.0,), 1e-6, 0.0)])


def test_tiny_and_point_probes_on_the_string_agree() -> None:
    """A point probe is exact on the string (closed form); a tiny footprint approaches it."""
    engine = ModalEngine(STRING, 100, 0.001)
    start = engine.start().state
    point = engine.step(start, [], [Probe((0.3,), 1e-5, 0.0)]).probes[0]
    tiny = engine.step(start, [], [Probe((0.3,), 1e-5, 1e-4)]).probes[0]
    assert point.compliance > 0.0
    # the footprint averages the kink of the string's Green's function: through the static
    # correction's 40000 modes, c(0) - c(r) = r / (c^2 sqrt(2 pi)) exactly (Gaussian average)
    kink = 1e-4 / (STRING.c**2 * math.sqrt(2.0 * math.pi))
    assert point.compliance - tiny.compliance == pytest.approx(kink, rel=1e-3)
    # a point probe's static compliance is the closed form x (1 - x) / c^2 in the static limit
    static = ModalEngine(STRING, 100, 10.0)  # no mode resolves the step: all static
    reading = static.step(static.start().state, [], [Probe((0.3,), 1e-5, 0.0)]).probes[0]
    assert static.modes.count == 0
    assert reading.compliance == pytest.approx(0.3 * 0.7 / STRING.c**2, rel=1e-12)


def test_a_footprint_larger_than_the_domain() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    reading = engine.step(engine.start().state, [], [Probe((0.5, 0.5), 1e-6, 5.0)]).probes[0]
    assert reading.in_contact and math.isfinite(reading.force) and reading.force > 0.0
    assert reading.displacement == pytest.approx(-1e-6, rel=1e-10)


def test_several_probes_solve_the_complementarity_problem() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.002)
    state = engine.start().state
    probes = [
        Probe((0.3, 0.5), 2e-5, 0.05),
        Probe((0.36, 0.5), 1e-6, 0.05),  # close: shadowed by its neighbour, lifts off
        Probe((0.7, 0.3), 1e-5, 0.07),
        Probe((0.7, 0.7), 0.0, 0.05),
    ]
    seen_shadow = False
    for _ in range(5):
        result = engine.step(state, [], probes, frame=False)
        state = result.state
        for probe, reading in zip(probes, result.probes, strict=True):
            assert reading.force >= 0.0 and reading.gap >= -1e-18
            assert reading.force * reading.gap == 0.0
            if reading.in_contact:
                assert reading.displacement == pytest.approx(-probe.depth, rel=1e-9, abs=1e-17)
        seen_shadow |= not result.probes[1].in_contact and result.probes[0].in_contact
    assert seen_shadow


def test_coincident_probes_share_the_force_of_one() -> None:
    """Two probes on the same footprint make a singular compliance matrix: still exact."""
    engine = ModalEngine(MEMBRANE, 20, 0.002)
    start = engine.start().state
    one = engine.step(start, [], [Probe((0.4, 0.6), 1e-5, 0.05)])
    two = engine.step(start, [], [Probe((0.4, 0.6), 1e-5, 0.05)] * 2)
    total = sum(r.force for r in two.probes)
    assert total == pytest.approx(one.probes[0].force, rel=1e-9)
    np.testing.assert_allclose(two.state.q, one.state.q, rtol=0, atol=1e-14)


def test_a_tip_above_the_rest_surface_meets_tissue_that_rings_up_to_it() -> None:
    """A signed depth: the tip held 1e-3 above the rest surface, the tissue ringing with
    amplitude 2e-3; the force is > 0 exactly on the steps whose gap is 0, and there the tissue
    sits at the tip's face."""
    engine = ModalEngine(MEMBRANE, 21, 0.002)
    x = np.linspace(0.0, 1.0, 21)
    ringing = 2e-3 * np.outer(np.sin(np.pi * x), np.sin(np.pi * x)).ravel()
    start = engine.start(ringing)
    assert start.displacement_residual < 1e-6
    above = Probe((0.5, 0.5), -1e-3, 0.05)
    free, held = start.state, start.state
    highest = touching = apart = 0.0
    for _ in range(250):
        unheld = engine.step(free, [], [Probe((0.5, 0.5), -1.0, 0.05)], frame=False)  # far above
        free, highest = unheld.state, max(highest, unheld.probes[0].displacement)
        reading = (result := engine.step(held, [], [above], frame=False)).probes[0]
        held = result.state
        assert (reading.force > 0.0) == (reading.gap == 0.0) == reading.in_contact
        if reading.in_contact:
            touching += 1
            assert reading.displacement == pytest.approx(1e-3, rel=1e-10)
        else:
            apart += 1
            assert reading.gap > 0.0 and reading.displacement < 1e-3
    assert highest > 1.5e-3  # the free tissue rings well past the tip
    assert touching > 10 and apart > 10


def test_a_held_probes_footprints_are_built_once_and_step_the_same_bits() -> None:
    """The basis keeps recent steps' footprints: a probe held still gets the same ones (the
    same arrays, not rebuilt), a moved one new ones, and the steps' bits do not depend on it
    (against the same engine with the memo cleared before every step)."""
    from membrane_models.live.cost import StepBudget, StepTooCostly

    engine = ModalEngine(MEMBRANE, 20, 0.002)
    basis = engine.basis
    held, moved = Probe((0.5, 0.5), 0.01, 0.05), Probe((0.4, 0.5), 0.01, 0.05)
    first = basis.footprints([], [held], engine.budget)[1][0]
    again = basis.footprints([], [held], engine.budget)[1][0]
    other = basis.footprints([], [moved], engine.budget)[1][0]
    assert first is not None and again is not None and other is not None
    assert again.spectra[0] is first.spectra[0] and other.spectra[0] is not first.spectra[0]
    remembered, fresh = engine.start().state, engine.start().state
    for k in range(40):
        probes = [held if (k // 7) % 2 == 0 else moved]
        a = engine.step(remembered, [], probes)
        basis.memo.clear()  # as if never seen
        basis._last = None
        b = engine.step(fresh, [], probes)
        assert a.frame is not None and b.frame is not None
        assert a.frame.tobytes() == b.frame.tobytes() and a.probes == b.probes
        remembered, fresh = a.state, b.state
    # The same inputs under a budget they break are priced, and refused, after passing another.
    basis.footprints([], [held], engine.budget)
    for probe in (held, moved):
        with pytest.raises(StepTooCostly):
            basis.footprints([], [probe], StepBudget(max_work=1.0))


def test_the_footprint_memo_keeps_many_sessions_inputs_within_its_bounds() -> None:
    """64 sessions' own probes stay remembered together (each gets its same footprints back);
    past the entry bound the least recently used go first, and the bytes stay bounded."""
    from membrane_models.live.footprint_memo import FootprintMemo

    engine = ModalEngine(MEMBRANE, 20, 0.002)
    basis = engine.basis
    probes = [Probe((0.1 + 0.0125 * i, 0.5), 0.01, 0.05) for i in range(64)]
    first = [basis.footprints([], [p], engine.budget)[1][0] for p in probes]
    again = [basis.footprints([], [p], engine.budget)[1][0] for p in probes]
    assert all(a is not None and b is not None and a.spectra[0] is b.spectra[0]
               for a, b in zip(first, again, strict=True))  # fmt: skip
    small: FootprintMemo[str] = FootprintMemo(max_entries=3, max_bytes=100)
    for key in "abcd":
        small.put(key, key.upper(), 10)
    assert len(small) == 3 and small.get("a") is None and small.get("d") == "D"
    small.put("big", "B", 60)  # over a quarter of the bytes: not kept, nothing pushed out
    assert small.get("big") is None and len(small) == 3
    for key in "efgh":
        small.put(key, key, 25)
    assert small._bytes <= 100
