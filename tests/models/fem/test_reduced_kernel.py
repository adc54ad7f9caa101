"""The reduced plate's compiled step (fem.reduced_kernel) against the numpy path it stands in
for: the same steps to Newton's tolerance through a press, a hold, a slide, a release and
free ringing, with every way out of the kernel taken (a fresh Jacobian needed, the contact set
changing, no tools), and the engine's steps the same either way."""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from membrane_models import fem
from membrane_models.fem import reduced_dynamics
from membrane_models.fem.damping import Damping
from membrane_models.fem.nonlinear_engine import NonlinearPlateEngine
from membrane_models.fem.reduced_dynamics import Solved, StepCoefficients, step_reduced
from membrane_models.fem.reduced_kernel import CONVERGED, compiled_chord
from membrane_models.fem.reduced_plate import ReducedPlate, reduce_plate
from membrane_models.fem.tissue import Tissue
from membrane_models.live.interface import Tool
from membrane_models.live.tools import tool_points

pytest.importorskip("numba", reason="the compiled step needs numba (the server extra)")

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
CENTRE = (0.025, 0.025)
DT = 1e-3


@functools.cache
def _plate() -> ReducedPlate:
    system = fem.assemble(fem.rectangle(0.05, 0.05, 0.005), SKIN, "clamped")
    return reduce_plate(system, 8, (21, 21), "held")


def _tools(k: int) -> list[Tool]:
    """A sphere pressed to 2 h over 150 steps, held, slid 2 mm, lifted away at step 400."""
    if k >= 400:
        return []
    depth = 2 * SKIN.thickness * min(k + 1, 150) / 150
    x = CENTRE[0] + 0.002 * min(max(k - 250, 0), 100) / 100
    return [Tool("sphere", (x, CENTRE[1]), depth, 0.005)]


def _run(chord: Any, steps: int = 600) -> tuple[list[Solved], Counter[str]]:
    """The press's steps, stepped as the engine does, with ``chord`` (None: numpy alone);
    what the kernel answered, counted."""
    plate = _plate()
    coefficients = StepCoefficients.of(plate, DT, 0.02)
    q, v = np.zeros(plate.size), np.zeros(plate.size)
    answered: Counter[str] = Counter()
    counted = None if chord is None else _counting(chord, answered)
    matrix, acceleration, last_points, forces = None, None, None, np.zeros(0)
    solved_steps = []
    for k in range(steps):
        row = tool_points(_tools(k), plate.coordinates, plate.movable, 64)
        same = last_points is not None and np.array_equal(row.indices, last_points)
        start = forces > 0.0 if same and forces.size else None
        solved = step_reduced(plate, coefficients, q, v, row.indices, row.surface, start=start,
                              matrix=matrix, acceleration=acceleration, chord=counted)  # fmt: skip
        acceleration = (solved.v - v) / DT
        q, v, matrix, forces, last_points = (
            solved.q,
            solved.v,
            solved.matrix,
            solved.forces,
            row.indices,
        )
        solved_steps.append(solved)
    return solved_steps, answered


def _counting(chord: Callable[..., Any], answered: Counter[str]) -> Callable[..., Any]:
    def counted(*arguments: Any) -> Any:
        out = chord(*arguments)
        answered["solved" if out[0] == CONVERGED else f"handed on ({out[0]})"] += 1
        return out

    return counted


def _largest_difference(one: list[Solved], other: list[Solved]) -> float:
    """The largest difference of q, v or the forces over the steps, each relative to its
    largest size over the run."""
    worst = 0.0
    for name in ("q", "v", "forces"):
        scale = max(float(np.abs(getattr(s, name)).max(initial=0.0)) for s in other)
        for a, b in zip(one, other, strict=True):
            left, right = getattr(a, name), getattr(b, name)
            assert left.shape == right.shape
            if left.size:
                worst = max(worst, float(np.abs(left - right).max()) / scale)
    return worst


@functools.cache
def _numpy_run() -> list[Solved]:
    return _run(None)[0]


def test_the_compiled_steps_are_the_numpy_steps_to_rounding() -> None:
    chord = compiled_chord()
    compiled, answered = _run(chord)
    # measured 1.7e-11 on this run: Newton's tolerance (1e-11 on the step), the kernel taking
    # more chord iterates before a fresh Jacobian than the numpy path does
    assert _largest_difference(compiled, _numpy_run()) < 1e-9
    # the kernel solved steps, and each way out of it was taken, so each is checked (counted:
    # 527 solved, 68 handed on for a fresh Jacobian, 1 at a change of the contact set: the
    # press is fast, 2 h in 0.15 s, and stiffening)
    assert answered["solved"] > 100
    assert {"handed on (2)", "handed on (3)"} <= set(answered)
    assert max(s.forces.sum() for s in compiled) > 0.5  # it pressed: about 1 N at 2 h


def test_a_kernel_off_by_a_rounding_would_be_caught() -> None:
    # the comparison's own power: a kernel whose q is off by 1e-7 of itself fails it (measured
    # 1.4e-5: the error carried on by the dynamics)
    chord = compiled_chord()
    assert chord is not None

    def off(*arguments: Any) -> Any:
        status, q, v, forces, displacement, iteration = chord(*arguments)
        return status, q * (1.0 + 1e-7), v, forces, displacement, iteration

    wrong, _ = _run(off, steps=200)
    assert _largest_difference(wrong, _numpy_run()[:200]) > 1e-9


def test_the_engine_steps_the_same_compiled_or_not(monkeypatch: pytest.MonkeyPatch) -> None:
    tissue = Tissue("skin patch", fem.rectangle(0.05, 0.05, 0.005), SKIN, "clamped",
                    Damping.modal(0.02), 8, (0.005,))  # fmt: skip
    plate = _plate()
    compiled = NonlinearPlateEngine(tissue, (21, 21), DT, plate=plate, adapted=False)
    plain = NonlinearPlateEngine(tissue, (21, 21), DT, plate=plate, adapted=False, compiled=False)
    assert compiled.compiled and not plain.compiled
    taken: Counter[str] = Counter()
    original = reduced_dynamics._compiled_step

    def counted(*arguments: Any) -> Any:
        taken["compiled"] += 1
        return original(*arguments)

    monkeypatch.setattr(reduced_dynamics, "_compiled_step", counted)
    a, b = compiled.start().state, plain.start().state
    for k in range(300):
        a = compiled.step(a, tools=_tools(k), frame=False).state
        b = plain.step(b, tools=_tools(k), frame=False).state
        assert a.forces.sum() == pytest.approx(b.forces.sum(), rel=1e-9, abs=1e-12)
    assert np.abs(a.q - b.q).max() <= 1e-9 * np.abs(b.q).max()
    assert taken["compiled"] > 250  # the compiled engine asked the kernel; the plain one never
