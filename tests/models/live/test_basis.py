"""The stepping core over any modal basis: the sine modes fed as tables step as the sine engine.

The tabulated basis is how FEM modes reach the live core. Fed the sine modes (mass-normalised
shapes 2^(d/2) prod sin on the lattice, footprints from the sine spectra, and the sine engine's
residual flexibility as its static correction), every frame, probe reading and energy must be
the sine engine's to 1e-12: the core does not depend on which modes it steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from membrane_models.live import Load, ModalEngine, Probe
from membrane_models.live.footprint import Footprint
from membrane_models.live.inputs import inside_domain
from membrane_models.live.sine_basis import SineBasis
from membrane_models.live.stepper import ModalStepper
from membrane_models.live.tabulated_basis import TableFootprint, TabulatedBasis
from membrane_models.problems import Problem, make_problem

TOLERANCE = 1e-12


@dataclass
class SineTables:
    """Footprints and static correction of the sine basis, answered through the tables' API."""

    sine: SineBasis
    prints: dict[tuple[tuple[float, ...], float], Footprint] = field(default_factory=dict)

    def contains(self, at: tuple[float, ...]) -> bool:
        return inside_domain(at)

    def refuses(self, radius: float) -> str | None:
        return None

    def modal_force(self, at: tuple[float, ...], radius: float) -> np.ndarray:
        footprint = self._sine_footprint(at, radius)
        return (2.0 ** (-self.sine.spatial_dims / 2)) * self.sine.modal_force(footprint).ravel()

    def compliance(self, a: TableFootprint, b: TableFootprint) -> float:
        return self.sine.cross(
            self._sine_footprint(a.at, a.radius), self._sine_footprint(b.at, b.radius)
        )

    def field(self, footprint: TableFootprint) -> np.ndarray:
        return self.sine.frame(
            self.sine_zeros(), [(self._sine_footprint(footprint.at, footprint.radius), 1.0)]
        )

    def sine_zeros(self) -> np.ndarray:
        return np.zeros(self.sine.modes.box)

    def _sine_footprint(self, at: tuple[float, ...], radius: float) -> Footprint:
        key = (at, radius)
        if key not in self.prints:
            item = Load(at, 1.0, radius)
            self.prints[key] = self.sine.footprint(
                item, self.sine.footprint_size(item, "load", 0), "load"
            )
        return self.prints[key]


def sine_tables(engine: ModalEngine) -> TabulatedBasis:
    """The sine engine's modes as a tabulated basis (mass-normalised: 2^(d/2) prod sin)."""
    sine = engine.basis
    axes = [np.linspace(0.0, 1.0, n) for n in sine.lattice_shape]
    per_axis = [
        np.sin(np.pi * np.outer(x, np.arange(1, k + 1)))
        for x, k in zip(axes, sine.modes.box, strict=True)
    ]
    for table in per_axis:
        table[[0, -1]] = 0.0
    shapes = per_axis[0]
    for table in per_axis[1:]:  # x-major points, box-order modes
        shapes = np.einsum("ia,jb->ijab", shapes, table).reshape(
            shapes.shape[0] * table.shape[0], -1
        )
    shapes *= 2.0 ** (sine.spatial_dims / 2)
    tables = SineTables(sine)
    return TabulatedBasis(
        sine.lattice_shape,
        shapes,
        sine.modes.omega.ravel(),
        tables,
        kept=sine.modes.kept.ravel(),
        correction=tables if sine.static_correction else None,
    )


def relative(a: np.ndarray, b: np.ndarray) -> float:
    scale = max(float(np.max(np.abs(b))), 1e-300)
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) / scale


MEMBRANE, STRING = make_problem("membrane-forced"), make_problem("string-forced")
CASES: dict[str, tuple[Problem, tuple[int, ...], dict[str, Any]]] = {
    "membrane-zoh": (MEMBRANE, (14, 12), {"damping": 0.0, "hold": "zoh"}),
    "membrane-foh-damped": (MEMBRANE, (12, 12), {"damping": 0.05, "hold": "foh"}),
    "membrane-uncorrected": (MEMBRANE, (12, 10), {"static_correction": False}),
    "string-zoh": (STRING, (40,), {"damping": 0.02, "hold": "zoh"}),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_sine_modes_as_tables_step_as_the_sine_engine(case: str) -> None:
    problem, lattice, options = CASES[case]
    engine = ModalEngine(problem, lattice, 0.01, **options)
    core = ModalStepper(
        sine_tables(engine), 0.01, damping=engine.damping, hold=engine.hold, budget=engine.budget
    )
    dims = len(lattice)
    centre = (0.4, 0.55)[:dims]
    initial = (
        np.outer(*(np.sin(np.pi * np.linspace(0, 1, n)) for n in lattice)) if dims == 2 else None
    )
    if initial is None:
        initial = np.sin(np.pi * np.linspace(0, 1, lattice[0])) ** 2
    initial = 1e-3 * initial.reshape(-1)
    sine_start, table_start = engine.start(initial), core.start(initial)
    assert table_start.displacement_residual == pytest.approx(
        sine_start.displacement_residual, abs=TOLERANCE
    )
    a, b = sine_start.state, table_start.state
    for step in range(12):
        loads = [Load((0.3, 0.6)[:dims], 2.0 * math.sin(0.7 * step), 0.08)]
        probes = [Probe(centre, 4e-4 * step, 0.06)]
        if step % 3 == 0:
            probes.append(Probe((0.7, 0.3)[:dims], 2e-4 * step, 0.1))
        if step == 5:
            probes.append(Probe((1.5, 0.5)[:dims], 0.0, 0.1))  # outside: touches nothing
        x, y = engine.step(a, loads, probes, work=True), core.step(b, loads, probes, work=True)
        assert x.frame is not None and y.frame is not None
        assert relative(y.frame, x.frame) <= TOLERANCE, (case, step)
        for rx, ry in zip(x.probes, y.probes, strict=True):
            assert rx.outside == ry.outside and rx.in_contact == ry.in_contact
            if not rx.outside:
                assert ry.force == pytest.approx(rx.force, rel=TOLERANCE, abs=1e-300)
                assert ry.displacement == pytest.approx(rx.displacement, rel=TOLERANCE, abs=1e-18)
                assert ry.compliance == pytest.approx(rx.compliance, rel=TOLERANCE)
        if x.work is not None:
            assert y.work == pytest.approx(x.work, rel=1e-10, abs=1e-18)
        assert core.energy(y.state) == pytest.approx(engine.energy(x.state), rel=1e-10)
        a, b = x.state, y.state


def test_a_wrong_table_would_be_caught() -> None:
    """Its power: one mode's frequency off by 1e-9 moves the frames beyond the tolerance."""
    engine = ModalEngine(MEMBRANE, (12, 12), 0.01)
    tables = sine_tables(engine)
    omega = tables.modes.omega.copy()
    omega[0] *= 1.0 + 1e-9
    off = TabulatedBasis(tables.lattice_shape, tables._shapes, omega, tables._footprints)
    core = ModalStepper(off, 0.01)
    a, b = engine.start().state, core.start().state
    worst = 0.0
    for _ in range(50):
        x = engine.step(a, [Load((0.5, 0.5), 1.0, 0.1)])
        y = core.step(b, [Load((0.5, 0.5), 1.0, 0.1)])
        assert x.frame is not None and y.frame is not None
        worst = max(worst, relative(y.frame, x.frame))
        a, b = x.state, y.state
    assert worst > TOLERANCE


def test_a_table_of_the_wrong_size_is_refused() -> None:
    from membrane_models.live import InvalidEngineSettings

    engine = ModalEngine(MEMBRANE, (8, 8), 0.01)
    tables = sine_tables(engine)
    with pytest.raises(InvalidEngineSettings, match="mode table"):
        TabulatedBasis((8, 7), tables._shapes, tables.modes.omega, tables._footprints)
