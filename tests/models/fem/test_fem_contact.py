"""Rigid tools pressed into FEM models (``fem.press``) against independent closed forms.

A circular membrane of radius a under tension T, clamped at its rim, small slopes:

- a flat punch of radius b pressed to depth d at the centre: w = -d ln(a / r) / ln(a / b)
  outside it, so F = 2 pi T d / ln(a / b);
- a sphere of radius R: it touches out to the contact radius c, where w and its slope match
  the paraboloid -d + r^2 / (2 R) (the small-slope sphere), so F = 2 pi T c^2 / R and
  d = (c^2 / R) (1/2 + ln(a / c)).

The meshes are rings (``fem_cases.polar_disk``) on P1 triangles; the punch's rim is a ring.
On a clamped square plate a point-sized tool needs the point stiffness 1 / (0.005612 a^2 / D).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fem_cases import UNIT_PLATE, polar_disk
from scipy.optimize import brentq

from membrane_models import fem
from membrane_models.live import InvalidTool, Tool

A, T = 0.025, 100.0  # a 50 mm disk at 100 N/m
MEMBRANE = fem.Membrane(T, 1.0)
POINT_CLAMPED = 0.005612  # w / (P a^2 / D), a clamped square plate (Timoshenko)


def _membrane(radii: np.ndarray, spokes: int) -> fem.System:
    return fem.assemble(polar_disk(radii, spokes), MEMBRANE, "clamped", element="p1")


def _punch_mesh(b: float, h: float) -> fem.System:
    inner = np.linspace(0.0, b, round(b / h) + 1)[1:]
    outer = np.linspace(b, A, round((A - b) / h) + 1)[1:]
    return _membrane(np.concatenate([inner, outer]), 64)


def test_a_flat_punch_needs_the_log_profiles_force_and_leaves_its_shape() -> None:
    b, d = 0.010, 1e-4
    system = _punch_mesh(b, 1e-3)
    pressed = fem.press(system, [Tool("cylinder", (0.0, 0.0), d, b)])
    (reading,) = pressed.readings
    exact = 2 * math.pi * T * d / math.log(A / b)  # 0.0686 N
    assert reading.force == pytest.approx(exact, rel=0.01)
    assert reading.penetration <= 1e-12 * d and reading.gap == 0.0
    radii = np.array([0.011, 0.013, 0.016, 0.02, 0.023])
    angles = np.linspace(0.3, 5.9, radii.size)
    points = radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    w = fem.sample(system, pressed.deflection, points)
    assert np.abs(w + d * np.log(A / radii) / math.log(A / b)).max() <= 0.01 * d
    # a punch 3 % narrower holds only the ring inside it (9 mm): 10 % off, so the rim counts
    narrow = fem.press(system, [Tool("cylinder", (0.0, 0.0), d, 0.97 * b)]).readings[0]
    assert abs(narrow.force / exact - 1) > 0.01


def test_a_sphere_touches_out_to_its_contact_radius_and_needs_its_force() -> None:
    radius, c = 0.1, 0.005  # slope c / R = 0.05 at the contact's edge
    d = (c * c / radius) * (0.5 + math.log(A / c))  # 0.527 mm
    h = 4e-4
    system = _membrane(np.concatenate([np.arange(h, 0.012, h), np.geomspace(0.012, A, 12)[1:]]), 96)
    pressed = fem.press(system, [Tool("sphere", (0.0, 0.0), d, radius)])
    (reading,) = pressed.readings
    exact = 2 * math.pi * T * c * c / radius  # 0.157 N
    assert reading.force == pytest.approx(exact, rel=0.01)
    touching = np.hypot(*pressed.points[pressed.forces > 0].T).max()
    assert touching == pytest.approx(c, abs=1.5 * h)
    assert reading.penetration <= 1e-12 * d
    # the contact law without the paraboloid's own depth c^2 / (2 R) is caught
    wrong_c = brentq(lambda x: (x * x / radius) * math.log(A / x) - d, 1e-4, 0.02)
    assert abs(reading.force / (2 * math.pi * T * wrong_c**2 / radius) - 1) > 0.05


def test_a_point_tool_on_the_clamped_plate_needs_the_point_stiffness() -> None:
    side, d = 1.0, 1e-3
    system = fem.assemble(fem.rectangle(side, side, side / 8), UNIT_PLATE, "clamped")
    tool = Tool("cylinder", (0.5, 0.5), d, 0.01)  # narrower than an element: the centre vertex
    (reading,) = fem.press(system, [tool]).readings
    assert reading.points == 1 and reading.contacts == 1
    stiffness = UNIT_PLATE.rigidity / (POINT_CLAMPED * side**2)
    assert reading.force == pytest.approx(stiffness * d, rel=0.01)


def test_a_tool_above_the_rest_surface_touches_only_tissue_pushed_up_to_it() -> None:
    system = _punch_mesh(0.01, 2e-3)
    lift = fem.pressure_load(system, 200.0)  # 200 Pa upward: the centre rises 0.31 mm
    free = fem.solve(system, lift)
    rise = float(fem.sample(system, free, np.array([[0.0, 0.0]]))[0])
    near = fem.press(system, [Tool("sphere", (0.0, 0.0), -0.5 * rise, 0.02)], lift)
    (touching,) = near.readings
    assert touching.force > 0 and touching.gap == 0.0
    centre = float(fem.sample(system, near.deflection, np.array([[0.0, 0.0]]))[0])
    assert centre == pytest.approx(0.5 * rise, rel=1e-9)
    (clear,) = fem.press(system, [Tool("sphere", (0.0, 0.0), -2 * rise, 0.02)], lift).readings
    assert clear.force == 0.0 and clear.gap == pytest.approx(rise, rel=1e-6)


def test_presses_that_cannot_be_solved_are_refused_with_the_reason() -> None:
    p2 = fem.assemble(fem.disk(A, 0.01), MEMBRANE, "clamped")
    with pytest.raises(fem.InvalidSolve, match=r'needs p1 triangles, not p2: .*element="p1"'):
        fem.press(p2, [Tool("sphere", (0.0, 0.0), 1e-4, 0.01)])
    p1 = _punch_mesh(0.01, 5e-3)
    with pytest.raises(InvalidTool, match="tool 0: kind must be 'sphere' or 'cylinder'"):
        fem.press(p1, [Tool("blade", (0.0, 0.0), 1e-4, 0.01)])
    with pytest.raises(fem.InvalidLoad, match="finite values"):
        fem.press(p1, [], np.full(p1.dofs, np.nan))
