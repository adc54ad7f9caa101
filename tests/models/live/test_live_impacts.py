"""A sudden press against an all-modes reference: the soft tip (Gaussian, radius 0.05) driven
to its depth in one step at dt = 1 ms, on the engine `membrane-live` serves.

The reference steps 512 modes per axis exactly (no step limit). The served engine steps 60 per
axis with the static correction for the rest; the lattice alone would resolve 18, whose first
step near a corner is less than half as stiff as the reference (the test below proves the check
would catch that).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from membrane_models.live import ModalEngine, Probe
from membrane_models.problems import make_problem
from membrane_server.scene import load_scene

RADIUS, DEPTH, DT, DAMPING = 0.05, 1e-3, 1e-3, 0.02
PLACES = ((0.5, 0.5), (0.5, 0.06), (0.2, 0.03))  # centre, near an edge, near a corner
TOLERANCE = 0.05


@cache
def _engine(modes: int, reference: bool = False) -> ModalEngine:
    """The engine on ``modes`` per axis; the reference steps them all, unbudgeted."""
    exact = {"step_limit": None, "budget": None} if reference else {}
    problem = make_problem("membrane-forced")
    return ModalEngine(problem, 20, DT, damping=DAMPING, modes=modes, **exact)  # type: ignore[arg-type]


def _forces(engine: ModalEngine, probes: list[Probe], steps: int = 5) -> np.ndarray:
    state, forces = engine.start().state, []
    for _ in range(steps):
        result = engine.step(state, (), probes, frame=False)
        state = result.state
        forces.append([reading.force for reading in result.probes])
    return np.array(forces)


def _worst_force_error(modes: int, at: tuple[float, float]) -> float:
    """The largest |F - F_ref| over steps 1-5, relative to the reference's largest force."""
    probes = [Probe(at, DEPTH, RADIUS)]
    ours, reference = _forces(_engine(modes), probes), _forces(_engine(512, True), probes)
    assert reference.max() > 0.0  # the press does touch
    return float(np.abs(ours - reference).max() / np.abs(reference).max())


def _one_step_compliance(engine: ModalEngine, places: list[tuple[float, float]]) -> np.ndarray:
    """Two probes' one-step compliance matrix: the stepped modes' response plus the correction."""
    basis, gain = engine.basis, engine.transition.zoh_q
    _, found = basis.footprints((), [Probe(at, DEPTH, RADIUS) for at in places], engine.budget)
    prints = [fp for fp in found if fp is not None]
    assert len(prints) == len(places)
    shapes = [basis.modal_force(fp) for fp in prints]
    return np.array([
        [float(np.vdot(gain * a, b)) * basis.scale + basis.cross(fa, fb)
         for b, fb in zip(shapes, prints, strict=True)]
        for a, fa in zip(shapes, prints, strict=True)
    ])  # fmt: skip


def test_the_served_scene_steps_the_modes_checked_here() -> None:
    assert load_scene("membrane-live").live.options["modes"] == 60  # type: ignore[union-attr]


@pytest.mark.slow
@pytest.mark.parametrize("at", PLACES)
def test_a_sudden_press_matches_the_all_modes_reference(at: tuple[float, float]) -> None:
    assert _worst_force_error(60, at) < TOLERANCE


@pytest.mark.slow  # over a second: the full suite runs it
def test_the_two_probe_compliance_matches_the_reference() -> None:
    places = [(0.45, 0.5), (0.55, 0.5)]
    ours = _one_step_compliance(_engine(60), places)
    reference = _one_step_compliance(_engine(512, True), places)
    assert np.abs(ours / reference - 1.0).max() < TOLERANCE


def test_the_lattice_resolved_modes_alone_would_be_caught() -> None:
    """The check's power: 18 modes per axis (what a 20-point lattice resolves) fail it."""
    assert _worst_force_error(18, PLACES[2]) > 2 * TOLERANCE
    places = [(0.45, 0.5), (0.55, 0.5)]
    ratio = _one_step_compliance(_engine(18), places) / _one_step_compliance(
        _engine(512, True), places
    )
    assert np.abs(ratio - 1.0).max() > 2 * TOLERANCE
