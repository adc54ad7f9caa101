"""The reduced von Karman plate (fem.reduced_plate, fem.reduced_dynamics) against the full one
on the same mesh: its energy's force, its static press, its free vibration and its energy."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from membrane_models import fem
from membrane_models.fem.nonlinear import solve_nonlinear
from membrane_models.fem.nonlinear_press import press_nonlinear
from membrane_models.fem.reduced_dynamics import StepCoefficients, press_reduced, step_reduced
from membrane_models.fem.reduced_plate import ReducedPlate, reduce_plate
from membrane_models.live.interface import Tool
from membrane_models.live.tools import tool_points

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
CENTRE = (0.025, 0.025)


@functools.cache
def _patch() -> fem.System:
    return fem.assemble(fem.rectangle(0.05, 0.05, 0.005), SKIN, "clamped")


@functools.cache
def _reduced(modes: int) -> ReducedPlate:
    return reduce_plate(_patch(), modes, (21, 21), "held")


def test_its_force_is_its_energys_gradient_and_its_quartic_is_symmetric() -> None:
    plate = _reduced(8)
    g = plate.quartic
    assert np.array_equal(g, np.transpose(g, (1, 0, 2, 3)))
    assert np.array_equal(g, np.transpose(g, (0, 1, 3, 2)))
    assert np.array_equal(g, np.transpose(g, (2, 3, 0, 1)))
    q = np.random.default_rng(1).normal(size=plate.size) * 1e-4
    step = 1e-9
    numeric = [
        (plate.stretching_energy(q + step * e) - plate.stretching_energy(q - step * e)) / (2 * step)
        for e in np.eye(plate.size)
    ]
    force = plate.stretching_force(q)
    assert np.abs(np.array(numeric) - force).max() <= 1e-7 * np.abs(force).max()


@pytest.mark.slow
def test_it_presses_as_the_full_plate_does_within_the_measured_error() -> None:
    # a centre point force: the linear limit exactly, then the stretch within the reduction's
    # error (12 modes and the residual: +0.07 % at 0.25 N, +0.67 % at 1 N; measured)
    system, plate = _patch(), _reduced(12)
    centre = int(np.argmin(((plate.coordinates - CENTRE) ** 2).sum(axis=1)))
    load = np.zeros(plate.size)
    for force, tolerance in ((0.01, 1e-4), (0.25, 2e-3), (1.0, 1e-2)):
        full = solve_nonlinear(system, fem.point_load(system, -force, CENTRE), "held")
        expected = fem.sample(system, full.w, [CENTRE])[0]
        pressed = press_reduced(plate, np.zeros(0, dtype=np.intp), np.zeros(0),
                                load=-force * plate.shapes[centre] + load)  # fmt: skip
        reduced = plate.shapes[centre] @ pressed.q - plate.residual[centre, centre] * force
        assert reduced == pytest.approx(expected, rel=tolerance)


@pytest.mark.slow
def test_a_punch_pressed_to_twice_the_thickness_takes_the_full_plates_force() -> None:
    # the validation press: a flat punch of 5 mm radius off the centre (at no point a basis
    # vector was built from: the basis is modes only), pressed to 6 mm = 2 h; the full plate
    # constrained at the same lattice points. Measured on this mesh, 20 modes: -0.50 % at 6 mm.
    system, plate = _patch(), reduce_plate(_patch(), 20, (20, 20), "held")
    at, depths = (0.019, 0.031), (0.002, 0.004, 0.006)
    tools = [[Tool("cylinder", at, depth, 0.005)] for depth in depths]
    rows = [tool_points(t, plate.coordinates, plate.movable, 64) for t in tools]
    full = press_nonlinear(system, rows[0].coordinates, [r.surface for r in rows], "held")
    start = None
    for row, reference in zip(rows, full, strict=True):
        reduced = press_reduced(plate, row.indices, row.surface, start=start)
        start = reduced.q
        assert reduced.forces.sum() == pytest.approx(reference.force, rel=0.01)
        assert np.abs(reduced.displacement - row.surface)[reduced.forces > 0].max() < 1e-12
    linear = fem.press(system, [Tool("cylinder", at, 0.006, 0.005)]).readings[0].force
    assert full[-1].force > 2 * linear  # the stretch: the linear plate is far off at 2 h


@pytest.mark.slow
def test_without_damping_or_contact_the_step_keeps_the_energy() -> None:
    # the discrete gradient: the quartic energy kept to Newton's tolerance over 10^4 steps of
    # a large vibration (about 0.9 h at the centre), where Newmark keeps it within 3e-3
    plate = _reduced(8)
    coefficients = StepCoefficients.of(plate, 1e-3, 0.0)
    q = np.zeros(plate.size)
    v = np.zeros(plate.size)
    v[0] = 0.9 * SKIN.thickness * plate.omega[0] / abs(plate.shapes[220, 0])
    none, nothing = np.zeros(0, dtype=np.intp), np.zeros(0)

    def energy(q: np.ndarray, v: np.ndarray) -> float:
        return 0.5 * v @ v + 0.5 * np.sum(plate.omega**2 * q * q) + plate.stretching_energy(q)

    start = energy(q, v)
    matrix = None
    energies = []
    for _ in range(10_000):
        solved = step_reduced(plate, coefficients, q, v, none, nothing, matrix=matrix)
        q, v, matrix = solved.q, solved.v, solved.matrix
        energies.append(energy(q, v))
    spread = (max(energies) - min(energies)) / start
    assert spread < 1e-10  # measured 1.2e-13 (Newmark on the full plate: 3.4e-3 over 2,000)
    assert plate.stretching_energy(q) > 0.0
