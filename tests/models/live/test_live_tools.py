"""Rigid tools: no lattice point under a tool above its surface, forces complementary to gaps,
and settled presses against closed forms (problem units: T = c^2, 100 on the string, 25 on the
membrane).

The membrane's flat punch is checked against the unit square's own closed form: for a punch of
radius b << 1 at the centre of a clamped square the field is that of a disk of the square's
conformal radius R_c = Gamma(1/4)^2 / (4 pi^(3/2)) = 0.5902 (the square's symmetry leaves an
error of order b^4), so F = 2 pi T d / ln(R_c / b).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from membrane_models.live import InvalidTool, ModalEngine, ModalState, Probe, Tool
from membrane_models.live.cost import StepBudget
from membrane_models.live.interface import StepResult
from membrane_models.live.tools import tool_points
from membrane_models.problems import make_problem
from membrane_models.sines import axis_sines

STRING = make_problem("string-forced")
MEMBRANE = make_problem("membrane-forced")
CONFORMAL_RADIUS = math.gamma(0.25) ** 2 / (4 * math.pi**1.5)  # the unit square's, from its centre
ROUNDING = 1e-12  # of the depth: what "nowhere above the tool" allows


def _run(
    engine: ModalEngine, tools: list[Tool], steps: int, state: ModalState | None = None
) -> list[StepResult[ModalState]]:
    state = engine.start().state if state is None else state
    results = []
    for _ in range(steps):
        result = engine.step(state, [], [], tools=tools)
        results.append(result)
        state = result.state
    return results


def _penetration(engine: ModalEngine, tools: list[Tool], frame: np.ndarray) -> float:
    basis = engine.basis
    points = tool_points(tools, basis.lattice_coordinates, basis.movable, 64)
    return float((frame[points.indices] - points.surface).max())


@pytest.mark.parametrize("kind", ["sphere", "cylinder"])
def test_no_lattice_point_under_a_tool_is_ever_above_it(kind: str) -> None:
    """membrane-live's engine, pressed in one step and held while the patch rings: every frame
    at or below the tool, to rounding, at every point under it."""
    engine = ModalEngine(MEMBRANE, 20, 0.001, damping=0.02)
    tools = [Tool(kind, (0.43, 0.52), 0.01, 0.12)]
    results = _run(engine, tools, 120)
    worst = max(_penetration(engine, tools, r.frame) for r in results if r.frame is not None)
    assert worst <= ROUNDING * 0.01
    assert max(r.tools[0].penetration for r in results) <= ROUNDING * 0.01
    assert results[0].tools[0].force > 0.0 and results[0].tools[0].contacts > 0


def test_forces_push_only_where_the_tissue_touches() -> None:
    """Complementarity at every point: F >= 0, F > 0 only where the gap is 0 (and the reading's
    gap is 0 exactly when some point is in contact)."""
    engine = ModalEngine(MEMBRANE, 20, 0.001, damping=0.02)
    tools = [Tool("sphere", (0.5, 0.5), 0.005, 0.15), Tool("cylinder", (0.25, 0.3), 0.002, 0.08)]
    for result in _run(engine, tools, 60):
        for reading in result.tools:
            assert reading.force >= 0.0
            assert (reading.gap == 0.0) == (reading.contacts > 0)
            assert reading.points > 0


def test_a_tool_above_the_rest_plane_touches_only_tissue_that_rings_up_to_it() -> None:
    """Signed depth: a tool held 1e-3 above the rest plane over tissue ringing at 2e-3 has a
    force exactly on the steps where its gap is 0."""
    engine = ModalEngine(MEMBRANE, 20, 0.001, damping=0.0)
    x, y = np.meshgrid(np.linspace(0, 1, 20), np.linspace(0, 1, 20), indexing="ij")
    ringing = 2e-3 * np.sin(np.pi * x) * np.sin(np.pi * y)
    state = engine.start(ringing.reshape(-1)).state
    tools = [Tool("cylinder", (0.5, 0.5), -1e-3, 0.1)]
    results = _run(engine, tools, 250, state)
    touching = [r.tools[0].force > 0.0 for r in results]
    assert any(touching) and not all(touching)
    for result, touched in zip(results, touching, strict=True):
        assert (result.tools[0].gap == 0.0) == touched


def test_a_point_under_two_tools_takes_the_lower_surface() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001, damping=0.02)
    deep, shallow = Tool("cylinder", (0.5, 0.5), 0.004, 0.1), Tool("sphere", (0.5, 0.5), 0.001, 0.1)
    results = _run(engine, [shallow, deep], 30)
    assert all(r.tools[0].points == 0 for r in results)  # every point belongs to the deeper
    assert _penetration(engine, [deep], results[-1].frame) <= ROUNDING * 0.004  # type: ignore[arg-type]


@pytest.mark.slow
def test_a_flat_punch_on_the_string_needs_the_kinked_strings_force() -> None:
    """A flat segment [a - w, a + w] held at depth d, settled: the string is straight from the
    clamps to the segment's ends, F = T d (1 / (a - w) + 1 / (1 - a - w))."""
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    d, a, w = 1e-3, 0.4, 0.1 + 1e-9  # the segment's ends on lattice points (spacing 0.01)
    results = _run(engine, [Tool("cylinder", (a,), d, w)], 600)
    reading = results[-1].tools[0]
    assert reading.force == pytest.approx(100.0 * d * (1 / 0.3 + 1 / 0.5), rel=1e-4)
    assert reading.contacts == 2  # the segment's ends: the string is straight between them


def _settled_punch_force(lattice: int, radius: float, depth: float) -> float:
    budget = StepBudget(max_work=1e9)  # a fine lattice's punch: costlier than a served step
    engine = ModalEngine(MEMBRANE, lattice, 0.01, damping=0.9, budget=budget)
    state = engine.start().state
    tool = Tool("cylinder", (0.5, 0.5), depth, radius)
    for _ in range(150):  # e^-20 of the slowest mode's transient at zeta 0.9
        result = engine.step(state, [], [], frame=False, tools=[tool])
        state = result.state
    return result.tools[0].force


@pytest.mark.slow  # over a second: the full suite runs it
def test_a_flat_punch_on_the_square_needs_the_conformal_radius_force() -> None:
    """Lattice 41 (spacing 0.025) under a punch of radius 0.1: within 1 % of
    F = 2 pi T d / ln(R_c / b) (measured +0.26 %; lattice 21: -4.3 %)."""
    radius, depth = 0.1, 1e-3
    exact = 2 * math.pi * 25.0 * depth / math.log(CONFORMAL_RADIUS / radius)
    force = _settled_punch_force(41, radius, depth)
    assert force == pytest.approx(exact, rel=1e-2)
    # the inscribed disk's radius (0.5) instead of the conformal radius is 7 % off: caught
    inscribed = 2 * math.pi * 25.0 * depth / math.log(0.5 / radius)
    assert abs(force / inscribed - 1) > 3e-2


@pytest.mark.slow  # over a second: the full suite runs it
def test_between_lattice_points_the_tissue_stays_within_the_stated_bound() -> None:
    """On a grid 4x finer than the lattice under a flat punch (settled), the tissue rises above
    the face between its points by at most 15 % of the depth at spacing / radius = 0.5
    (measured 14.0 %; 7.6 % at 0.25: about 0.3 spacing / radius, docs/LIVE.md)."""
    engine = ModalEngine(MEMBRANE, 21, 0.01, damping=0.9)
    tool = Tool("cylinder", (0.5, 0.5), 1e-3, 0.1)
    state = _run(engine, [tool], 150)[-1].state
    basis = engine.basis
    coefficients = np.array(state.q)
    spread = [(fp, f) for fp, f in state.applied if f != 0.0]
    box = basis.residual.combined(spread)
    total = np.zeros(tuple(max(a, b) for a, b in zip(box.shape, coefficients.shape, strict=True)))
    total[: box.shape[0], : box.shape[1]] += box
    total[: coefficients.shape[0], : coefficients.shape[1]] += coefficients
    fine = np.linspace(0.4, 0.6, 4 * 4 + 1)
    sines = axis_sines(fine, total.shape[0])
    field = sines @ total @ axis_sines(fine, total.shape[1]).T
    fx, fy = np.meshgrid(fine, fine, indexing="ij")
    under = (fx - 0.5) ** 2 + (fy - 0.5) ** 2 <= 0.1**2 * (1 - 1e-9)
    rise = float((field[under] + 1e-3).max())
    assert 0.0 < rise <= 0.15 * 1e-3


@pytest.mark.parametrize(
    ("tools", "probes", "message"),
    [
        ([Tool("blade", (0.5, 0.5), 0.01, 0.1)], [], "kind must be"),
        ([Tool("sphere", (0.5, 0.5), 0.01, 0.0)], [], "radius > 0"),
        ([Tool("sphere", (0.5, 0.5), 0.01, 0.5)], [], "more than the 64"),
        ([Tool("sphere", (0.5, 0.5), 0.01, 0.1)], [Probe((0.2, 0.2), 0.0, 0.05)], "not both"),
        ([Tool("sphere", (0.5, 0.5), 2e3, 0.1)], [], "depth must be"),
        ([Tool("sphere", (0.5, 0.5), 0.01, 0.1)] * 5, [], "at most 4 tools"),
    ],
)
def test_bad_tools_are_refused_with_the_reason(
    tools: list[Tool], probes: list[Probe], message: str
) -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.start().state
    with pytest.raises(InvalidTool, match=message):
        engine.step(state, [], probes, tools=tools)


def test_a_tool_between_lattice_points_touches_nothing_and_says_so() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    result = engine.step(engine.start().state, tools=[Tool("sphere", (0.5, 0.5), 0.01, 0.01)])
    reading = result.tools[0]
    assert (reading.points, reading.force) == (0, 0.0) and math.isnan(reading.gap)
