"""FEM modes in the live core: tables read between their nodes, static limits, contact, cache.

A coarse clamped plate (the study's skin patch material, 50 mm square, Argyris) keeps every
test under a second or two; the tables are built once per module.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from membrane_models import fem
from membrane_models.fem.cache import TableCache, cached_tables
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tables import LiveTables, footprint_loads, live_tables
from membrane_models.live import Grasp, InvalidLoad, InvalidProbe, Load, Probe, Tool
from membrane_models.live.stepper import ModalStepper

SIDE = 0.05
SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
RADIUS = 0.004
MODES = 40
Plate = tuple[fem.System, fem.Modes, LiveTables]


@pytest.fixture(scope="module")
def plate() -> Plate:
    system = fem.assemble(fem.rectangle(SIDE, SIDE, 0.005), SKIN, "clamped")
    modes = fem.modes(system, MODES)
    return system, modes, live_tables(system, modes, (9, 9), [RADIUS, 2 * RADIUS])


def _static(
    system: fem.System, radius: float, centres: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exact load vectors and static responses K^-1 f of unit footprints at ``centres``."""
    loads = footprint_loads(system, radius, centres)
    return loads, np.stack([fem.solve(system, f) for f in loads.T], axis=1)


def test_tables_read_between_nodes_within_1e_3_of_the_compliance(plate: Plate) -> None:
    system, modes, tables = plate
    basis = fem_basis(tables)
    rng = np.random.default_rng(7)
    centres = rng.uniform(0.006, SIDE - 0.006, size=(6, 2))
    loads, responses = _static(system, RADIUS, centres)
    exact_forces = modes.shapes.T @ loads
    for k, at in enumerate(map(tuple, centres)):
        footprint = basis._footprint(Load(at, 1.0, RADIUS), "load", 0)
        compliance = float(loads[:, k] @ responses[:, k])  # f' K^-1 f, m/N
        force_error = np.linalg.norm(footprint.modal_force - exact_forces[:, k])
        assert force_error <= 1e-3 * np.linalg.norm(exact_forces[:, k])
        stepped = float(np.sum(footprint.modal_force**2 / modes.omega**2))
        assert abs(stepped + basis.own(footprint) - compliance) <= 1e-3 * compliance


def test_a_held_load_settles_on_the_static_deflection(plate: Plate) -> None:
    system, _, tables = plate
    engine = ModalStepper(fem_basis(tables), 2e-4, damping=0.9)
    at = (0.021, 0.027)
    state = engine.start().state
    for _ in range(400):
        state = engine.step(state, [Load(at, -2.0, RADIUS)], frame=False).state
    loads, responses = _static(system, RADIUS, np.array([at]))
    expected = -2.0 * float(loads[:, 0] @ responses[:, 0])
    probe = engine.step(state, [Load(at, -2.0, RADIUS)], [Probe(at, 0.0, RADIUS)]).probes[0]
    assert not probe.in_contact  # the load pushes the tissue away from the tip (-w)
    assert probe.displacement == pytest.approx(expected, rel=1e-3)
    lattice = fem.tables.lattice_points(tables.lower, tables.upper, tables.lattice)
    frame = engine.frame(state)
    exact = fem.sample(system, -2.0 * responses[:, 0], lattice[tables.inside])
    assert np.max(np.abs(frame[tables.inside] - exact)) <= 1e-3 * np.max(np.abs(exact))


def test_a_probe_pressed_into_the_patch_feels_its_static_stiffness(plate: Plate) -> None:
    system, _, tables = plate
    engine = ModalStepper(fem_basis(tables), 2e-4, damping=0.9)
    at, depth = (0.025, 0.025), 1e-4  # 0.1 mm
    state = engine.start().state
    for _ in range(400):
        result = engine.step(state, [], [Probe(at, depth, RADIUS)], frame=False)
        state = result.state
    loads, responses = _static(system, RADIUS, np.array([at]))
    stiffness = 1.0 / float(loads[:, 0] @ responses[:, 0])  # N/m under the footprint
    reading = result.probes[0]
    assert reading.in_contact and reading.displacement == pytest.approx(-depth, rel=1e-9)
    assert reading.force == pytest.approx(stiffness * depth, rel=1e-3)


def test_footprints_the_tables_do_not_carry_are_refused(plate: Plate) -> None:
    engine = ModalStepper(fem_basis(plate[2]), 1e-3)
    state = engine.start().state
    with pytest.raises(InvalidProbe, match=r"probe 0: radius 0.001 m: .* 4 mm, 8 mm only"):
        engine.step(state, [], [Probe((0.02, 0.02), 0.0, 0.001)])
    with pytest.raises(InvalidLoad, match="lies outside the domain"):
        engine.step(state, [Load((0.06, 0.02), 1.0, RADIUS)])
    outside = engine.step(state, [], [Probe((-0.01, 0.02), 0.0, RADIUS)]).probes[0]
    assert outside.outside and outside.force == 0.0


def test_the_tables_come_back_from_the_cache_and_a_damaged_entry_is_rebuilt(
    tmp_path: Path,
) -> None:
    domain = fem.rectangle(SIDE, SIDE, 0.01)
    cache = TableCache(tmp_path)
    options: dict[str, Any] = {"count": 8, "lattice": (5, 5), "radii": [0.008]}
    built, hit = cached_tables(domain, SKIN, "clamped", cache=cache, **options)
    assert not hit
    (entry,) = tmp_path.glob("*.npz")
    again, hit = cached_tables(domain, SKIN, "clamped", cache=cache, **options)
    assert hit and np.array_equal(again.shapes, built.shapes)
    assert np.array_equal(again.cross[(0, 0)], built.cross[(0, 0)])
    other, hit = cached_tables(domain, SKIN, "simply_supported", cache=cache, **options)
    assert not hit and not np.array_equal(other.omega, built.omega)  # another key
    data = bytearray(entry.read_bytes())
    data[len(data) // 2] ^= 0xFF
    entry.write_bytes(bytes(data))
    rebuilt, hit = cached_tables(domain, SKIN, "clamped", cache=cache, **options)
    assert not hit and np.array_equal(rebuilt.shapes, built.shapes)


def test_rayleigh_damping_decays_each_mode_at_its_own_ratio(plate: Plate) -> None:
    """C = alpha M + beta K: mode k decays as a damped oscillator of ratio alpha / 2w + beta w / 2
    (the stepper's per-mode ratios; every mode's exact transition)."""
    _, modes, tables = plate
    damping = fem.Damping.rayleigh(alpha=20.0, beta=2e-5)
    ratios = damping.ratios(modes.omega)
    engine = ModalStepper(fem_basis(tables), 1e-4, damping=ratios)
    start = engine.start(tables.shapes[:, 0] + tables.shapes[:, 5])
    state = start.state
    for _ in range(300):
        state = engine.step(state, frame=False).state
    t = 300 * 1e-4
    for k in (0, 5):
        zeta, w = ratios[k], modes.omega[k]
        wd = w * math.sqrt(1 - zeta**2)
        expected = math.exp(-zeta * w * t) * (math.cos(wd * t) + zeta * w / wd * math.sin(wd * t))
        assert state.q[k] == pytest.approx(expected * start.state.q[k], rel=1e-9, abs=1e-12)
    assert engine.describe()["damping"] == "per mode"
    uniform = ModalStepper(fem_basis(tables), 1e-4, damping=np.full(modes.count, 0.05))
    scalar = ModalStepper(fem_basis(tables), 1e-4, damping=0.05)
    for name in ("qq", "qv", "vq", "vv", "zoh_q", "foh1_v"):
        np.testing.assert_allclose(
            getattr(uniform.transition, name), getattr(scalar.transition, name), rtol=1e-13
        )


def test_inside_the_boundary_of_a_disk_and_of_a_polygon_with_a_hole() -> None:
    from membrane_models.fem.inside import inside_boundary
    from membrane_models.fem.live_basis import _fills_its_box
    from membrane_models.fem.tables import boundary_segments

    system = fem.assemble(fem.disk(0.02, 0.004, (0.02, 0.02)), SKIN, "clamped")
    segments = boundary_segments(system)
    angles = np.linspace(0.0, 2 * np.pi, 50, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    assert inside_boundary(0.02 + 0.019 * ring, segments, 1e-15).all()
    assert not inside_boundary(0.02 + 0.021 * ring, segments, 1e-15).any()
    assert not _fills_its_box(segments, (0.0, 0.0), (0.04, 0.04))
    square = fem.assemble(fem.rectangle(SIDE, SIDE, 0.01), SKIN, "clamped")
    assert _fills_its_box(boundary_segments(square), (0.0, 0.0), (SIDE, SIDE))
    holed = [[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]], [[1.0, 1.0], [0.0, 1.0]],
             [[0.0, 1.0], [0.0, 0.0]], [[0.4, 0.4], [0.6, 0.4]], [[0.6, 0.4], [0.6, 0.6]],
             [[0.6, 0.6], [0.4, 0.6]], [[0.4, 0.6], [0.4, 0.4]]]  # fmt: skip
    points = np.array([[0.2, 0.5], [0.5, 0.5], [0.5, 0.4], [1.2, 0.5]])
    assert inside_boundary(points, np.array(holed), 1e-12).tolist() == [True, False, True, False]


def test_a_grasp_lifting_the_patch_needs_its_static_stiffness_upward(plate: Plate) -> None:
    """The probe's check with the sign turned: a grasp holding the footprint 0.1 mm up needs
    +stiffness x height, beside a probe held clear above it (force 0)."""
    system, _, tables = plate
    engine = ModalStepper(fem_basis(tables), 2e-4, damping=0.9)
    at, height = (0.025, 0.025), 1e-4
    clear = Probe((0.01, 0.01), -1e-3, RADIUS)  # 1 mm above the rest surface
    state = engine.start().state
    for _ in range(400):
        result = engine.step(state, [], [clear], frame=False, grasps=[Grasp(at, height, RADIUS)])
        state = result.state
    loads, responses = _static(system, RADIUS, np.array([at]))
    stiffness = 1.0 / float(loads[:, 0] @ responses[:, 0])
    held = result.grasps[0]
    assert held.displacement == pytest.approx(height, rel=1e-9)
    assert held.force == pytest.approx(stiffness * height, rel=1e-3)
    assert result.probes[0].force == 0.0


def test_a_rigid_tool_on_the_plate_keeps_every_node_under_it_at_or_below_its_face(
    plate: Plate,
) -> None:
    """A flat tool over the centre node, pressed slowly and held: the node never rises above
    its face, and the force settles (skin-patch's point tables check it against the point
    probe: tests/server/test_tissue_scenes.py)."""
    _, _, tables = plate
    engine = ModalStepper(fem_basis(tables), 1e-3, damping=0.5)
    node = 4 * 9 + 4  # the centre of the 9 x 9 lattice
    at = tuple(float(x) for x in engine.basis.lattice_coordinates[node])
    depth, state, forces = 1e-4, engine.start().state, []
    for k in range(400):
        d = depth * min(1.0, (k + 1) / 200)
        result = engine.step(state, tools=[Tool("cylinder", at, d, 1e-3)])
        assert result.frame is not None and result.frame[node] <= -d * (1 - 1e-12)
        assert result.tools[0].points == 1
        forces.append(result.tools[0].force)
        state = result.state
    assert forces[-1] > 0.0 and forces[-50] == pytest.approx(forces[-1], rel=1e-4)
