"""Contact-adapted vectors added to the reduced plate (fem.adapted_basis, fem.basis_follower):
the same plate as a whole build with them, a state carried onto them continuously, a sphere
pressed to twice the thickness within 2 % of the full plate, and the engine following a tool."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from membrane_models import fem
from membrane_models.fem.adapted_basis import Adaptation, AdaptedPlate, carried
from membrane_models.fem.basis_follower import BasisFollower
from membrane_models.fem.damping import Damping
from membrane_models.fem.nonlinear_engine import NonlinearPlateEngine
from membrane_models.fem.nonlinear_press import press_nonlinear
from membrane_models.fem.reduced_dynamics import press_reduced
from membrane_models.fem.reduced_plate import ReducedPlate, reduce_plate
from membrane_models.fem.tissue import Tissue
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.live.interface import Tool
from membrane_models.live.tools import ToolPoints, tool_points

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
OFF_CENTRE = (0.019, 0.031)
DEPTHS = (0.002, 0.004, 0.006)


@functools.cache
def _patch() -> fem.System:
    return fem.assemble(fem.rectangle(0.05, 0.05, 0.00625), SKIN, "clamped")  # 694 DOFs


@functools.cache
def _base() -> ReducedPlate:
    return reduce_plate(_patch(), 20, (20, 20), "held")


@functools.cache
def _adaptation() -> Adaptation:
    return Adaptation.of(_patch(), _base(), "held")


def _rows(at: tuple[float, float], kind: str = "sphere") -> list[ToolPoints]:
    plate = _base()
    return [tool_points([Tool(kind, at, d, 0.005)], plate.coordinates, plate.movable, 64)
            for d in DEPTHS]  # fmt: skip


def _pressed(plate: ReducedPlate, rows: list[ToolPoints]) -> float:
    start = None
    for row in rows:
        solved = press_reduced(plate, row.indices, row.surface, start=start)
        start = solved.q
    return float(solved.forces.sum())


def _skin_tissue() -> Tissue:
    """The skin patch on the 6.25 mm mesh, its 20 modes: the engines' tissue here."""
    return Tissue("skin patch", fem.rectangle(0.05, 0.05, 0.00625), SKIN, "clamped",
                  Damping(), 20, (0.005,))  # fmt: skip


def _energy(plate: ReducedPlate, q: np.ndarray, v: np.ndarray) -> float:
    return float(0.5 * v @ v + 0.5 * np.sum(plate.omega**2 * q * q) + plate.stretching_energy(q))


@pytest.mark.slow
def test_an_added_vector_gives_the_plate_a_whole_build_with_it_gives() -> None:
    # the same span and the same condensed stretch: the press agrees with reduce_plate's own
    # static vector (Ritz-rotated, so compared by what it presses) to rounding
    adapted = _adaptation().adapted([OFF_CENTRE]).plate
    whole = reduce_plate(_patch(), 20, (20, 20), "held", static_points=[OFF_CENTRE])
    rows = _rows(OFF_CENTRE)
    assert _pressed(adapted, rows) == pytest.approx(_pressed(whole, rows), rel=1e-9)
    g = adapted.quartic
    assert np.array_equal(g, np.transpose(g, (1, 0, 2, 3)))
    assert np.array_equal(g, np.transpose(g, (2, 3, 0, 1)))
    assert np.array_equal(g[:20, :20, :20, :20], _base().quartic)  # the modes' rows kept
    vectors = adapted.vectors
    mass = vectors.T @ (_patch().mass @ vectors)
    stiffness = vectors.T @ (_patch().stiffness @ vectors)
    assert np.abs(mass - np.eye(21)).max() < 1e-10
    off = stiffness - np.diag(np.diag(stiffness))
    assert np.abs(off).max() < 1e-9 * stiffness.max()
    assert np.sqrt(np.diag(stiffness)) == pytest.approx(adapted.omega, rel=1e-9)


@pytest.mark.slow
def test_the_sphere_pressed_to_twice_the_thickness_takes_the_full_plates_force() -> None:
    # off the centre, where the 20 modes alone are 5.2 % low at 6 mm (the skin patch's mesh:
    # 5.18 %, docs/NONLINEAR.md); the adapted vector at the tool's centre, measured -0.66 %
    rows = _rows(OFF_CENTRE)
    full = press_nonlinear(_patch(), rows[0].coordinates, [r.surface for r in rows], "held")
    adapted = _adaptation().adapted([OFF_CENTRE]).plate
    assert _pressed(adapted, rows) == pytest.approx(full[-1].force, rel=0.02)
    assert _pressed(_base(), rows) < 0.97 * full[-1].force


def test_a_state_moves_onto_an_added_vector_without_a_jump() -> None:
    # from the modes alone: the same displacement everywhere and the same energy, to rounding
    base, adapted = _base(), _adaptation().adapted([OFF_CENTRE])
    rng = np.random.default_rng(3)
    q = rng.normal(size=base.size) * 2e-5
    v = rng.normal(size=base.size) * 1e-3
    moved_q, moved_v = carried(q, base, adapted), carried(v, base, adapted)
    plate = adapted.plate
    before, after = base.shapes @ q, plate.shapes @ moved_q
    assert np.abs(after - before).max() <= 1e-14 * np.abs(before).max()
    assert plate.vectors @ moved_q == pytest.approx(base.vectors @ q, rel=1e-14, abs=0.0)
    assert _energy(plate, moved_q, moved_v) == pytest.approx(_energy(base, q, v), rel=1e-13)


def test_a_pressed_state_moved_to_a_nearby_vector_jumps_little() -> None:
    # pressed at 6 mm on the vector at the tool's centre, then carried onto the vector 0.5 mm
    # away: what the first vector carried outside the second's span is dropped
    # (the mass-orthogonal projection). Measured: the lattice's displacement moves by 0.88 %
    # of the deepest point's and the energy by -0.77 %.
    adaptation = _adaptation()
    here = adaptation.adapted([OFF_CENTRE])
    there = adaptation.adapted([(OFF_CENTRE[0] + 0.0005, OFF_CENTRE[1])])
    start = None
    for row in _rows(OFF_CENTRE):
        solved = press_reduced(here.plate, row.indices, row.surface, start=start)
        start = solved.q
    q = solved.q
    moved = carried(q, here, there)
    before, after = here.plate.shapes @ q, there.plate.shapes @ moved
    jump = float(np.abs(after - before).max()) / float(np.abs(before).max())
    assert 0.0 < jump < 0.015
    zero = np.zeros(q.size)
    energy = _energy(here.plate, q, zero)
    assert abs(_energy(there.plate, moved, zero[: moved.size]) - energy) < 0.015 * energy
    # back to the first vector: its own coordinates again, less what the second lacked
    back = carried(moved, there, here)
    assert np.array_equal(back[:20], q[:20])
    assert abs(back[20]) <= abs(q[20])


def test_the_follower_rounds_the_tools_places_and_keeps_a_basis_while_it_fits() -> None:
    follower = BasisFollower(functools.partial(Adaptation.of, _patch(), _base(), "held"),
                             0.00025)  # fmt: skip
    places = follower.places([(0.01907, 0.03101), (0.01907, 0.03101)])
    assert len(places) == 1 and places[0] == pytest.approx((0.019, 0.031), abs=1e-15)
    basis = AdaptedPlate(_base(), ((0.019, 0.031),), np.zeros((_patch().dofs, 0)))
    assert follower.fits(basis, [(0.0192, 0.0311)])  # within the spacing of its point
    assert not follower.fits(basis, [(0.0193, 0.031)])
    assert not follower.fits(basis, [(0.019, 0.031), (0.03, 0.03)])  # a second tool
    assert follower.fits(basis, []) and follower.fits(None, [])  # no tool: nothing to adapt
    assert not follower.fits(None, [(0.019, 0.031)])


@pytest.mark.slow
def test_the_engine_steps_onto_the_tools_vector_once_it_is_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a tool held above the ringing plate, its vector built off the step (in the worker); the
    # step that moves onto it is the step on the modes alone but for the new coordinate's own
    # small motion, and a press goes on from it
    monkeypatch.setenv("MEMBRANE_CACHE_DIR", str(tmp_path))
    tissue = _skin_tissue()
    engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3)
    plain = NonlinearPlateEngine(tissue, (20, 20), 1e-3, adapted=False)
    try:
        assert engine.follower is not None
        shape = np.zeros(400)
        shape[209] = -0.001  # a dent at the centre: the plate rings in its modes
        state = engine.start(displacement=shape).state
        alone = plain.start(displacement=shape).state
        above = Tool("sphere", (0.025, 0.025), -0.004, 0.005)
        state = engine.step(state, tools=[above]).state  # asks for the vector
        alone = plain.step(alone, tools=[above]).state
        assert state.adapted is None and state.q.size == 20
        engine.follower.wait()
        moved = engine.step(state, tools=[above], frame=False).state
        alone = plain.step(alone, tools=[above]).state
        assert moved.adapted is not None and moved.adapted.points == ((0.025, 0.025),)
        assert moved.q.size == 21
        # measured: the frames 8.0e-6 of the dent apart, the energies equal (no damping)
        change = np.abs(engine.frame(moved) - plain.frame(alone)).max()
        assert change < 1e-4 * np.abs(engine.frame(state)).max()
        assert engine.energy(moved) == pytest.approx(plain.energy(alone), rel=1e-9)
        for k in range(1, 201):
            tool = Tool("sphere", (0.025, 0.025), 0.003 * k / 200, 0.005)
            result = engine.step(moved, tools=[tool])
            moved = result.state
        assert moved.adapted is not None and result.tools[0].force > 0.5
    finally:
        engine.close()


def _press_forces(engine: NonlinearPlateEngine, steps: int = 30) -> tuple[list[float], bool]:
    """A sphere pressed at the centre from rest: the force each step, and whether the first
    step was taken on the tool's vector."""
    state = engine.start().state
    forces, first_adapted = [], False
    for k in range(1, steps + 1):
        tool = Tool("sphere", (0.025, 0.025), 0.003 * k / steps, 0.005)
        result = engine.step(state, tools=[tool], frame=False)
        state = result.state
        first_adapted = first_adapted or (k == 1 and state.adapted is not None)
        forces.append(result.tools[0].force)
    return forces, first_adapted


@pytest.mark.slow
def test_a_press_waiting_for_its_vector_is_the_same_whatever_the_build_took(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # with adapted_build "wait" the first press of a fresh engine (its vector built while it
    # waits) and a later press (the vector long built) are the same to the bit; beside, the
    # first press goes on the modes alone while its vector is built, and they differ
    monkeypatch.setenv("MEMBRANE_CACHE_DIR", str(tmp_path))
    tissue = _skin_tissue()
    waiting = NonlinearPlateEngine(tissue, (20, 20), 1e-3, adapted_build="wait")
    beside = NonlinearPlateEngine(tissue, (20, 20), 1e-3)
    try:
        said, default = waiting.describe()["adapted"], beside.describe()["adapted"]
        assert isinstance(said, dict) and isinstance(default, dict)
        assert said == {**default, "build": "wait"} and default["build"] == "beside"
        first, first_adapted = _press_forces(waiting)
        again, _ = _press_forces(waiting)
        assert first_adapted and first == again
        assert beside.follower is not None
        cold, cold_adapted = _press_forces(beside)
        beside.follower.wait()
        warm, warm_adapted = _press_forces(beside)
        assert not cold_adapted and warm_adapted and warm == first
        assert abs(cold[-1] - warm[-1]) > 1e-3 * warm[-1]
    finally:
        waiting.close()
        beside.close()


def test_adapted_build_takes_beside_or_wait() -> None:
    tissue = _skin_tissue()
    with pytest.raises(InvalidEngineSettings, match="adapted_build must be one of beside, wait"):
        NonlinearPlateEngine(tissue, (20, 20), 1e-3, adapted_build="later")


@pytest.mark.slow
def test_a_basis_the_worker_cannot_build_leaves_the_state_on_its_own() -> None:
    # an adaptation that fails in the worker (no system to adapt): the place is given up,
    # the step goes on with the basis it has and never asks again
    broken = functools.partial(Adaptation.of, None, None, "held")  # type: ignore[arg-type]
    failing = BasisFollower(broken, 0.00025)
    try:
        assert failing.follow(None, [OFF_CENTRE]) is None  # asked
        failing.wait()
        assert failing.follow(None, [OFF_CENTRE]) is None  # given up
        assert failing._refused == {failing.places([OFF_CENTRE])}
    finally:
        failing.close()
    # waiting for it: the step that asks is told at once that the place is given up
    waiting = BasisFollower(broken, 0.00025, wait=True)
    try:
        assert waiting.follow(None, [OFF_CENTRE]) is None
        assert waiting._refused == {waiting.places([OFF_CENTRE])}
    finally:
        waiting.close()
    # a worker that cannot even start (a System does not pickle): the modes alone, no error
    unstartable = BasisFollower(functools.partial(Adaptation.of, _patch(), _base(), "held"),
                                0.00025)  # fmt: skip
    try:
        assert unstartable.follow(None, [OFF_CENTRE]) is None
        unstartable.wait()
        assert unstartable.follow(None, [OFF_CENTRE]) is None
    finally:
        unstartable.close()
