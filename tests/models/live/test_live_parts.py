"""The engine's parts against independent computations: spectra, synthesis, contact, residual."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import quad

from membrane_models.live import InvalidProbe, ModalEngine, Probe
from membrane_models.live import synthesis as synthesis_module
from membrane_models.live.contact import solve_contact
from membrane_models.live.footprint import axis_spectrum
from membrane_models.live.synthesis import LatticeSynthesis
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]


@pytest.mark.parametrize(
    ("centre", "radius"),
    [(0.5, 0.05), (0.2, 0.05), (0.0, 0.05), (1.0, 0.1), (0.03, 0.01), (0.5, 5.0), (0.7, 0.0)],
)
def test_footprint_spectrum_is_twice_the_sine_integral(centre: float, radius: float) -> None:
    count = 40
    got = axis_spectrum(centre, radius, count, cache=False)
    for m in (1, 2, 7, 23, 40):
        if radius == 0.0:
            expected = 2.0 * math.sin(m * math.pi * centre)
        else:

            def g(x: float, m: int = m) -> float:
                gauss = math.exp(-((x - centre) ** 2) / radius**2) / (math.sqrt(math.pi) * radius)
                return gauss * math.sin(m * math.pi * x)

            expected = 2.0 * quad(g, 0.0, 1.0, points=[centre], limit=400, epsabs=1e-14)[0]
        assert got[m - 1] == pytest.approx(expected, abs=1e-11)


def test_synthesis_folds_modes_beyond_the_lattice_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    shape = (9, 7)
    coefficients = rng.standard_normal((40, 33))
    x, y = (np.linspace(0.0, 1.0, n) for n in shape)
    direct = np.einsum(
        "im,jn,mn->ij",
        np.sin(np.pi * np.outer(x, np.arange(1, 41))),
        np.sin(np.pi * np.outer(y, np.arange(1, 34))),
        coefficients,
    ).reshape(-1)
    dense = LatticeSynthesis(shape).frame(coefficients)
    monkeypatch.setattr(synthesis_module, "DENSE_TABLE_ELEMENTS", 10)
    folded = LatticeSynthesis(shape).frame(coefficients)
    np.testing.assert_allclose(dense, direct, atol=1e-12)
    np.testing.assert_allclose(folded, direct, atol=1e-12)
    line = rng.standard_normal(50)
    direct_1d = np.sin(np.pi * np.outer(x, np.arange(1, 51))) @ line
    np.testing.assert_allclose(LatticeSynthesis((9,)).frame(line), direct_1d, atol=1e-12)


def _brute_force(c: FloatArray, b: FloatArray) -> FloatArray:
    """Every active set: the one whose forces and gaps are both non-negative."""
    n = b.size
    for size in range(n + 1):
        for chosen in itertools.combinations(range(n), size):
            active = list(chosen)
            force = np.zeros(n)
            if active:
                force[active] = np.linalg.solve(c[np.ix_(active, active)], b[active])
            gap = c @ force - b
            if force.min() >= -1e-12 and gap.min() >= -1e-12 * np.abs(b).max():
                return force
    raise AssertionError("no solution")


@pytest.mark.parametrize("seed", range(12))
def test_contact_matches_brute_force_enumeration(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 9))
    factor = rng.standard_normal((n, n + 2))
    c = factor @ factor.T + 0.1 * np.eye(n)
    b = rng.standard_normal(n)
    force = solve_contact(c, b)
    gap = c @ force - b
    assert force.min() >= 0.0 and gap.min() >= -1e-12 * np.abs(b).max()
    assert abs(force @ gap) <= 1e-10 * np.abs(b).max() * max(1.0, force.max())
    np.testing.assert_allclose(force, _brute_force(c, b), rtol=1e-9, atol=1e-12)


def test_contact_with_a_singular_compliance() -> None:
    s = np.array([[1.0, 2.0], [1.0, 2.0], [0.5, -1.0]])
    c = s @ s.T  # rank 2: the first two probes share a footprint
    b = np.array([1.0, 1.0, -0.5])
    force = solve_contact(c, b)
    gap = c @ force - b
    assert force.min() >= 0.0 and gap.min() >= -1e-12 and abs(force @ gap) < 1e-12
    with pytest.raises(InvalidProbe):
        solve_contact(np.zeros((2, 2)), np.array([1.0, -1.0]))  # pressed where nothing moves


def test_residual_cross_compliance_is_symmetric() -> None:
    engine = ModalEngine(make_problem("membrane-forced"), 20, 0.01)
    pa, pb = Probe((0.3, 0.6), 0.0, 0.05), Probe((0.05, 0.5), 0.0, 0.12)
    a = engine._footprint(pa, engine.footprint_size(pa, "probe", 0), "probe")
    b = engine._footprint(pb, engine.footprint_size(pb, "probe", 1), "probe")
    assert engine.residual.cross(a, b) == pytest.approx(engine.residual.cross(b, a), rel=1e-12)
    assert engine.residual.cross(a, a) > 0.0
