"""Bad input is refused before anything is solved: rigid bodies, parts, points, counts, models.

Every refusal is a ``FemError`` (a ``membrane_errors.UserError``) in one line.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from fem_cases import NU, UNIT_PLATE

from membrane_errors import UserError
from membrane_models import fem
from membrane_models.fem.assembly import assemble
from membrane_models.fem.modal import modes as lowest_modes
from membrane_models.fem.tables import MAX_BUILD_BYTES, build_bytes, live_tables

SQUARE = fem.rectangle(1.0, 1.0, 0.25)


def _refused(error: pytest.ExceptionInfo[fem.FemError]) -> str:
    message = str(error.value)
    assert isinstance(error.value, UserError) and "\n" not in message
    return message


@pytest.mark.parametrize(
    ("supports", "free"),
    [("free", 3), ({"left": "simply_supported"}, 1), ({}, 3)],
)
def test_a_plate_left_with_rigid_body_motions_is_refused(supports: object, free: int) -> None:
    with pytest.raises(fem.RigidBodyModes) as error:
        fem.assemble(SQUARE, UNIT_PLATE, supports)  # type: ignore[arg-type]
    assert f"{free} rigid-body motion" in _refused(error)


def test_pretension_alone_leaves_the_free_plate_its_translation() -> None:
    plate = fem.Plate(UNIT_PLATE.youngs_modulus, NU, 1.0, 1.0, pretension=1.0)
    with pytest.raises(fem.RigidBodyModes, match="1 rigid-body motion"):
        fem.assemble(SQUARE, plate, "free")


def test_a_free_membrane_is_refused() -> None:
    with pytest.raises(fem.RigidBodyModes, match="membrane"):
        fem.assemble(SQUARE, fem.Membrane(1.0, 1.0), "free")


def test_held_enough_the_plate_is_solved() -> None:
    """A cantilever; a plate on two simply supported sides; a free plate on a foundation,
    whose rigid motions ride the foundation at omega^2 = k / (rho h)."""
    for supports in (
        {"left": "clamped"},
        {"left": "simply_supported", "right": "simply_supported"},
    ):
        assert fem.modes(fem.assemble(SQUARE, UNIT_PLATE, supports), 1).omega[0] > 0
    floating = fem.Plate(UNIT_PLATE.youngs_modulus, NU, 1.0, 1.0, foundation=50.0)
    omega = fem.modes(fem.assemble(SQUARE, floating, "free"), 4).omega
    np.testing.assert_allclose(omega[:3], math.sqrt(50.0), rtol=1e-9)
    assert omega[3] > 2 * math.sqrt(50.0)


def test_unknown_parts_and_conditions_are_refused() -> None:
    with pytest.raises(fem.InvalidSupports, match="no boundary part 'rim'") as error:
        fem.assemble(SQUARE, UNIT_PLATE, {"rim": "clamped"})
    assert "left" in _refused(error)
    with pytest.raises(fem.InvalidSupports, match="unknown condition 'pinned'"):
        fem.assemble(SQUARE, UNIT_PLATE, {"left": "pinned"})
    with pytest.raises(fem.InvalidModel, match="p2"):
        fem.assemble(SQUARE, fem.Membrane(1.0, 1.0), "clamped", element="argyris")


def test_points_off_the_mesh_are_refused() -> None:
    system = fem.assemble(SQUARE, UNIT_PLATE, "clamped")
    with pytest.raises(fem.OutsideDomain, match=r"\(1.5, 0.5\)") as error:
        fem.point_load(system, 1.0, (1.5, 0.5))
    _refused(error)
    with pytest.raises(fem.OutsideDomain, match="reaches off"):
        fem.patch_load(system, 1.0, (0.9, 0.5), 0.2)
    u = fem.solve(system, fem.pressure_load(system, 1.0))
    with pytest.raises(fem.OutsideDomain, match=r"\(-0.1, 0.5\)"):
        fem.sample(system, u, [(0.5, 0.5), (-0.1, 0.5)])
    with pytest.raises(fem.InvalidLoad, match="radius"):
        fem.patch_load(system, 1.0, (0.5, 0.5), 0.0)
    with pytest.raises(fem.InvalidLoad, match="finite"):
        fem.point_load(system, math.nan, (0.5, 0.5))


def test_mode_counts_are_checked_and_modes_are_mass_normalised() -> None:
    system = fem.assemble(SQUARE, UNIT_PLATE, "clamped")
    for count in (0, system.free + 1, 2.5):
        with pytest.raises(fem.InvalidSolve, match="mode"):
            fem.modes(system, count)  # type: ignore[arg-type]
    modes = fem.modes(system, 5)
    np.testing.assert_allclose(modes.shapes.T @ system.mass @ modes.shapes, np.eye(5), atol=1e-9)
    np.testing.assert_allclose(
        modes.shapes.T @ system.stiffness @ modes.shapes, np.diag(modes.omega**2), atol=1e-6
    )
    assert (np.diff(modes.omega) >= 0).all()
    assert np.allclose(modes.frequency, modes.omega / (2 * math.pi))
    vertex = system.vertex_values(modes.shapes)
    assert (vertex[np.argmax(np.abs(vertex), axis=0), np.arange(5)] > 0).all()


def test_sampled_fields_have_the_shape_of_their_points() -> None:
    system = fem.assemble(SQUARE, fem.Membrane(2.0, 1.0), "clamped")
    u = fem.solve(system, fem.pressure_load(system, 1.0))
    assert np.shape(fem.sample(system, u, (0.5, 0.5))) == ()
    assert fem.sample(system, u, [(0.5, 0.5), (0.2, 0.3)]).shape == (2,)
    both = np.column_stack([u, 2 * u])
    assert fem.sample(system, both, [(0.5, 0.5)]).shape == (1, 2)
    assert fem.sampler(system, [(0.5, 0.5)]).shape == (1, system.dofs)
    with pytest.raises(fem.InvalidSolve, match="plate"):
        fem.surface_stress(system, u, (0.5, 0.5))


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"poisson": 0.6}, "poisson"),
        ({"thickness": -1.0}, "thickness"),
        ({"youngs_modulus": math.inf}, "youngs_modulus"),
        ({"density": True}, "density"),
        ({"pretension": -1.0}, "pretension"),
        ({"foundation": -1.0}, "foundation"),
    ],
)
def test_bad_plates_are_refused(fields: dict[str, float], match: str) -> None:
    values = {"youngs_modulus": 1e6, "poisson": 0.3, "thickness": 0.01, "density": 1e3} | fields
    with pytest.raises(fem.InvalidModel, match=match) as error:
        fem.Plate(**values)
    _refused(error)


def test_plate_and_membrane_derived_values() -> None:
    plate = fem.Plate(1.5e6, 0.45, 0.003, 1109.0)
    assert plate.rigidity == pytest.approx(1.5e6 * 0.003**3 / (12 * (1 - 0.45**2)))
    assert plate.areal_density == pytest.approx(1109.0 * 0.003)
    assert fem.Membrane(4.0, 0.25).wave_speed == pytest.approx(4.0)
    with pytest.raises(fem.InvalidModel, match="tension"):
        fem.Membrane(0.0, 1.0)


def test_damping_gives_each_mode_its_ratio() -> None:
    omega = np.array([10.0, 100.0, 1000.0])
    assert np.allclose(fem.Damping.modal(0.02).ratios(omega), 0.02)
    rayleigh = fem.Damping.rayleigh(alpha=2.0, beta=1e-4)
    assert np.allclose(rayleigh.ratios(omega), 2.0 / (2 * omega) + 1e-4 * omega / 2)
    assert np.allclose(fem.Damping().ratios(omega), 0.0)
    with pytest.raises(fem.InvalidModel, match="not both"):
        fem.Damping(zeta=0.1, alpha=1.0)
    with pytest.raises(fem.InvalidModel, match="zeta"):
        fem.Damping.modal(-0.1)
    with pytest.raises(fem.InvalidModel, match="angular"):
        rayleigh.ratios([0.0])


@pytest.mark.slow
def test_the_fem_room_imports_neither_torch_nor_the_learned_models() -> None:
    code = (
        "import sys, membrane_models.fem; "
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith(('torch.', "
        "'membrane_models.learned'))]; print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_live_tables_too_large_to_build_are_refused_before_the_build() -> None:
    """A footprint small for its domain: its tables' centres go as (size / radius)^2, so a
    0.1 mm footprint on a 50 mm disk would need hundreds of GiB; refused at once, saying so."""
    system = assemble(fem.disk(0.05, 0.01), fem.Membrane(100.0, 1.0), "clamped")
    modes = lowest_modes(system, 4)
    box = ((-0.05, -0.05), (0.05, 0.05))
    assert build_bytes(system, modes, *box, 400, [1e-4]) > MAX_BUILD_BYTES
    assert build_bytes(system, modes, *box, 400, [5e-3]) < MAX_BUILD_BYTES  # a usable radius
    with pytest.raises(fem.InvalidSolve) as error:
        live_tables(system, modes, (20, 20), [1e-4])
    message = _refused(error)
    assert "GiB to build" in message and "0.1 mm" in message and "100 x 100 mm" in message
