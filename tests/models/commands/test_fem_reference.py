"""The closed forms `membrane fem modes` prints beside the FEM frequencies."""

from __future__ import annotations

import math
from argparse import Namespace

import numpy as np
import pytest
from scipy import special

from membrane_models import fem
from membrane_models.commands.fem_reference import (
    CLAMPED_SQUARE_FIRST,
    clamped_disk_roots,
    closed_form,
    membrane_disk,
    membrane_rectangle,
    plate_clamped_disk,
    plate_clamped_square,
    plate_simply_supported_rectangle,
)
from membrane_models.commands.fem_setup import Tissue, tissue

SKIN = fem.Plate(1.5e6, 0.45, 0.003, 1109.0)


def test_the_clamped_disk_plate_roots_are_leissas() -> None:
    """Leissa (1969) table 2.1: lambda^2 = 10.2158, 21.260, 34.877 (n = 0, 1, 2), 39.771."""
    first = clamped_disk_roots(0, 10.0)
    assert first[0] == pytest.approx(3.1962, abs=1e-4)
    assert first[0] ** 2 == pytest.approx(10.2158, abs=1e-4)
    assert first[1] ** 2 == pytest.approx(39.771, abs=1e-3)
    assert clamped_disk_roots(1, 5.0)[0] ** 2 == pytest.approx(21.260, abs=1e-3)
    assert clamped_disk_roots(2, 6.0)[0] ** 2 == pytest.approx(34.877, abs=1e-3)
    for n, root in ((0, first[0]), (3, clamped_disk_roots(3, 8.0)[0])):  # roots of the equation
        value = special.jv(n, root) * special.ivp(n, root) - special.iv(n, root) * special.jvp(
            n, root
        )
        assert abs(value) < 1e-10 * special.iv(n, root)


def test_the_disk_plate_lists_n_at_least_one_in_pairs_in_ascending_order() -> None:
    reference = plate_clamped_disk(SKIN, 0.02, 6)
    assert reference.labels == ("n=0,k=1", "n=1,k=1", "n=1,k=1", "n=2,k=1", "n=2,k=1", "n=0,k=2")
    scale = math.sqrt(SKIN.rigidity / SKIN.areal_density) / 0.02**2 / (2 * math.pi)
    assert reference.frequencies[0] == pytest.approx(10.2158 * scale, rel=1e-5)
    assert list(reference.frequencies) == sorted(reference.frequencies)


def test_the_membrane_disk_uses_the_zeros_of_j_n() -> None:
    reference = membrane_disk(c=2.0, radius=0.5, count=4)
    expected = [
        special.jn_zeros(0, 1)[0],
        *[special.jn_zeros(1, 1)[0]] * 2,
        special.jn_zeros(2, 1)[0],
    ]
    np.testing.assert_allclose(
        reference.frequencies, 2.0 * np.array(expected) / 0.5 / (2 * math.pi)
    )
    assert reference.labels[:3] == ("n=0,k=1", "n=1,k=1", "n=1,k=1")


def test_the_membrane_rectangle_orders_m_and_n() -> None:
    reference = membrane_rectangle(c=1.0, a=2.0, b=1.0, count=4)
    assert reference.labels == ("m=1,n=1", "m=2,n=1", "m=3,n=1", "m=1,n=2")
    assert reference.frequencies[0] == pytest.approx(0.5 * math.sqrt(0.25 + 1.0))


def test_the_simply_supported_plate_carries_its_tension_and_foundation() -> None:
    plate = fem.Plate(1.5e6, 0.45, 0.003, 1109.0, pretension=10.0, foundation=1e6)
    reference = plate_simply_supported_rectangle(plate, 0.05, 0.04, 3)
    k2 = math.pi**2 * (1 / 0.05**2 + 1 / 0.04**2)
    omega2 = (plate.rigidity * k2**2 + 10.0 * k2 + 1e6) / plate.areal_density
    assert reference.frequencies[0] == pytest.approx(math.sqrt(omega2) / (2 * math.pi), rel=1e-12)
    assert reference.labels == ("m=1,n=1", "m=2,n=1", "m=1,n=2")


def test_a_foundation_shifts_omega_squared_by_k_over_rho_h() -> None:
    bare, held = SKIN, fem.Plate(1.5e6, 0.45, 0.003, 1109.0, foundation=2e6)
    f0 = plate_clamped_square(bare, 0.05).frequencies[0]
    f1 = plate_clamped_square(held, 0.05).frequencies[0]
    assert (2 * math.pi * f1) ** 2 - (2 * math.pi * f0) ** 2 == pytest.approx(2e6 / (1109 * 0.003))
    assert 2 * math.pi * f0 == pytest.approx(
        CLAMPED_SQUARE_FIRST / 0.05**2 * math.sqrt(bare.rigidity / bare.areal_density)
    )


def _tissue(shape: str, size: str, supports: str = "clamped", **model: str) -> Tissue:
    options = {
        "model": "plate",
        "youngs_modulus": "1.5MPa",
        "poisson": 0.45,
        "thickness": "3mm",
        "density": "1109kg/m3",
        "tension": None,
        "foundation": None,
    }
    options.update(model)
    args = Namespace(
        shape=shape,
        size=size,
        vertices=None,
        hole=[],
        mesh=None,
        element_size="25mm",
        supports=supports,
        **options,
    )
    return tissue(args)


def _title(item: Tissue) -> str | None:
    reference = closed_form(item, 3)
    return None if reference is None else reference.title.split(":")[0]


def test_closed_forms_exist_only_where_the_shape_and_supports_have_one() -> None:
    assert _title(_tissue("disk", "40mm")) == "clamped disk plate"
    square = closed_form(_tissue("square", "50mm"), 3)
    assert square is not None and len(square.frequencies) == 1  # the first mode only
    assert _title(_tissue("rectangle", "50mmx40mm")) is None  # clamped, not square
    assert _title(_tissue("disk", "40mm", "simply_supported")) is None
    assert _title(_tissue("disk", "40mm", tension="5N/m")) is None
    ss = _tissue("rectangle", "50mmx40mm", "simply_supported", tension="5N/m")
    assert _title(ss) == "simply supported plate"
    membrane = _tissue("disk", "40mm", "simply_supported", model="membrane", tension="50N/m")
    assert _title(membrane) == "fixed membrane disk"
    mixed = _tissue("square", "50mm", "left=clamped,right=clamped,top=clamped,bottom=free")
    assert _title(mixed) is None
    uniform = _tissue("square", "50mm", "left=clamped,right=clamped,top=clamped,bottom=clamped")
    assert _title(uniform) == "clamped square plate"
