"""The membrane's frequencies against the rectangle's sines and the disk's Bessel zeros.

P2 triangles (isoparametric on the disk's rim): the frequencies converge at order 4, and the
lowest six land within 0.1% on the finest mesh here. A polygon with a hole (gmsh) converges to
a refined reference.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fem_cases import observed_order
from scipy.special import jn_zeros

from membrane_models import fem

MEMBRANE = fem.Membrane(tension=4.0, areal_density=0.25)  # c = 4 m/s
COUNT = 6


def _worst(omega: np.ndarray, exact: np.ndarray) -> float:
    return float(np.abs(omega / exact - 1).max())


def test_rectangle_frequencies_match_the_sines_at_order_four() -> None:
    a, b = 1.0, 0.7
    c = MEMBRANE.wave_speed
    exact = np.sort(
        [c * math.pi * math.hypot(m / a, n / b) for m in range(1, 8) for n in range(1, 8)]
    )[:COUNT]
    sizes = [0.1, 0.05]
    errors = []
    for size in sizes:
        system = fem.assemble(fem.rectangle(a, b, size), MEMBRANE, "clamped")
        modes = fem.modes(system, COUNT)
        errors.append(_worst(modes.omega, exact))
        mass = modes.shapes.T @ system.mass @ modes.shapes
        np.testing.assert_allclose(mass, np.eye(COUNT), atol=1e-10)
    assert errors[-1] < 0.001
    assert observed_order(errors, sizes) > 3.3


def test_disk_frequencies_match_the_bessel_zeros_at_order_four() -> None:
    radius = 0.5
    c = MEMBRANE.wave_speed
    zeros = [z for n in range(4) for z in jn_zeros(n, 3) for _ in range(1 if n == 0 else 2)]
    exact = c * np.sort(zeros)[:COUNT] / radius
    sizes = [0.13 * radius, 0.066 * radius]  # 1024 and 4096 triangles
    errors = []
    for size in sizes:
        domain = fem.disk(radius, size)
        modes = fem.modes(fem.assemble(domain, MEMBRANE, "clamped"), COUNT)
        errors.append(_worst(modes.omega, exact))
    assert errors[-1] < 0.001
    assert observed_order(errors, sizes) > 3.3


@pytest.mark.slow
def test_a_polygon_with_a_hole_converges_to_a_refined_reference() -> None:
    pytest.importorskip("gmsh")
    outer = [(0.0, 0.0), (1.0, 0.0), (1.1, 0.9), (0.0, 0.8)]
    hole = [(0.3, 0.3), (0.6, 0.35), (0.45, 0.6)]

    def lowest(size: float) -> np.ndarray:
        domain = fem.polygon(outer, size, holes=[hole])
        assert set(domain.parts) == {"outer", "hole0"}
        system = fem.assemble(domain, MEMBRANE, {"outer": "clamped", "hole0": "clamped"})
        return fem.modes(system, 3).omega

    reference = lowest(0.02)
    sizes = [0.2, 0.1, 0.05]
    errors = [_worst(lowest(size), reference) for size in sizes]
    assert errors[-1] < 0.002
    # the hole's re-entrant corners make the modes singular: a lower order than 4
    assert observed_order(errors, sizes) > 1.0


def test_a_free_hole_lowers_the_frequencies() -> None:
    pytest.importorskip("gmsh")
    outer = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    hole = [(0.4, 0.4), (0.6, 0.4), (0.6, 0.6), (0.4, 0.6)]
    domain = fem.polygon(outer, 0.1, holes=[hole])
    fixed = fem.modes(fem.assemble(domain, MEMBRANE, "clamped"), 1).omega[0]
    free = fem.modes(fem.assemble(domain, MEMBRANE, {"outer": "clamped"}), 1).omega[0]
    assert free < fixed


def test_a_curved_rim_is_sampled_between_its_chords_and_its_arc() -> None:
    """The membrane's rim triangles bulge to the circle: a point outside the chords but inside
    the disk is read (w ~ 0 there, w > 0 inside), and the static deflection under a uniform
    pressure is the closed form q (R^2 - r^2) / (4 T)."""
    radius = 0.5
    domain = fem.disk(radius, 0.13)
    system = fem.assemble(domain, MEMBRANE, "clamped")
    u = fem.solve(system, fem.pressure_load(system, 1.0))
    rim = np.sort(
        np.arctan2(*domain.mesh.p[::-1, np.unique(domain.mesh.facets[:, domain.parts["rim"]])])
    )
    between = 0.5 * (rim[0] + rim[1])
    r = radius * (1 - 1e-3)
    assert radius * math.cos((rim[1] - rim[0]) / 2) < r  # off the chord
    at = np.array([[r * math.cos(between), r * math.sin(between)], [0.2, 0.1], [0.0, 0.0]])
    exact = (radius**2 - (at**2).sum(axis=1)) / (4 * MEMBRANE.tension)
    np.testing.assert_allclose(fem.sample(system, u, at), exact, rtol=2e-3, atol=1e-7)
    with pytest.raises(fem.OutsideDomain):
        fem.sample(system, u, (radius * 1.001, 0.0))
