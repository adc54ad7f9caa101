"""Quantities with units: what people type, what they are told when it cannot be read."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from membrane_errors import UserError
from membrane_models.physical import KINDS, UNITS, UnitError, format_quantity, parse_quantity


@pytest.mark.parametrize(
    ("text", "kind", "si"),
    [
        ("50mm", "length", 0.05),
        ("2.5 cm", "length", 0.025),
        ("40um", "length", 40e-6),
        ("40µm", "length", 40e-6),
        ("1.5MPa", "pressure", 1.5e6),
        ("1 kPa", "pressure", 1e3),
        ("0.2GPa", "pressure", 2e8),
        ("250mN", "force", 0.25),
        ("-1N", "force", -1.0),
        ("1109kg/m3", "density", 1109.0),
        ("1109 kg/m^3", "density", 1109.0),
        ("1.1g/cm³", "density", 1100.0),
        ("50N/m", "tension", 50.0),
        ("1kPa/mm", "foundation", 1e6),
        ("3e6 N/m3", "foundation", 3e6),
        ("20ms", "time", 0.02),
        ("50us", "time", 5e-5),
        ("1.5kHz", "frequency", 1500.0),
        ("+.5mm", "length", 5e-4),
        ("1E-3m", "length", 1e-3),
    ],
)
def test_quantities_come_back_in_si(text: str, kind: str, si: float) -> None:
    assert parse_quantity(text, kind) == pytest.approx(si, rel=1e-15)


def test_a_bare_number_asks_for_a_unit_and_names_the_flag() -> None:
    with pytest.raises(UnitError) as error:
        parse_quantity("50", "length", name="--size")
    assert str(error.value) == "--size 50: give a unit, e.g. 50mm"
    assert isinstance(error.value, UserError)  # one line and exit code 2 at the command line
    assert parse_quantity("0", "pressure") == 0.0  # zero is zero in every unit
    assert parse_quantity("12.5", "length", default_unit="mm") == 0.0125  # --at, --vertices


def test_a_unit_of_another_kind_or_none_is_refused_with_the_accepted_ones() -> None:
    with pytest.raises(
        UnitError,
        match=r"^--size 2kPa: kPa is a pressure, not a length; "
        r"a length takes m, cm, mm, um$",
    ):
        parse_quantity("2kPa", "length", name="--size")
    with pytest.raises(UnitError, match=r"unknown unit 'furlong'; a length takes m, cm, mm, um"):
        parse_quantity("3 furlong", "length")
    with pytest.raises(UnitError, match=r"not a number with a unit, e.g. 50N"):
        parse_quantity("one newton", "force")


def test_the_table_catches_the_slip_a_bare_number_or_a_case_would_hide() -> None:
    """Its power: 1.5 (Pa? MPa?) and 1.5mPa (a millipascal: 1e9 times too soft) are the two
    ways a modulus goes wrong silently; both are refused, the second with the unit meant."""
    with pytest.raises(UnitError, match=r"^--E 1.5: give a unit, e.g. 1.5kPa$"):
        parse_quantity("1.5", "pressure", name="--E")
    with pytest.raises(UnitError, match=r"unknown unit 'mPa' \(did you mean MPa\?\)"):
        parse_quantity("1.5mPa", "pressure", name="--E")
    with pytest.raises(UnitError, match=r"unknown unit 'mpa' \(did you mean MPa\?\)"):
        parse_quantity("1.5 mpa", "pressure")


@pytest.mark.parametrize(
    "text", ["inf mm", "-infinity mm", "nan", "NaN kPa", "1e999mm", "1e308GPa"]
)
def test_values_that_are_not_finite_are_refused(text: str) -> None:
    kind = "pressure" if "Pa" in text or text == "nan" else "length"
    with pytest.raises(UnitError, match="must be finite"):
        parse_quantity(text, kind, name="--x")


def test_an_unknown_kind_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="unknown kind of quantity 'mass'"):
        parse_quantity("1kg", "mass")


@pytest.mark.parametrize(
    ("value", "kind", "text"),
    [
        (0.003315, "length", "3.315 mm"),
        (0.05, "length", "50 mm"),
        (2.5e-7, "length", "0.25 um"),
        (12.0, "length", "12 m"),
        (1.5e6, "pressure", "1.5 MPa"),
        (999.96, "pressure", "1 kPa"),
        (999.4, "pressure", "999.4 Pa"),
        (-0.25, "force", "-250 mN"),
        (1109.0, "density", "1109 kg/m3"),
        (5e6, "foundation", "5 kPa/mm"),
        (5e-5, "time", "50 us"),
        (0.02, "time", "20 ms"),
        (0.0, "time", "0 s"),
        (1500.0, "frequency", "1.5 kHz"),
    ],
)
def test_values_are_written_in_a_readable_unit(value: float, kind: str, text: str) -> None:
    assert format_quantity(value, kind) == text


_UNITS = [(kind, unit) for kind in KINDS for unit in UNITS[kind]]
_VALUES = st.floats(min_value=1e-9, max_value=1e9, allow_nan=False) | st.just(0.0)


@given(st.sampled_from(_UNITS), _VALUES, st.booleans())
def test_every_unit_reads_its_own_scale_and_every_written_value_reads_back(
    unit: tuple[str, str], value: float, negative: bool
) -> None:
    kind, name = unit
    value = -value if negative else value
    scale = UNITS[kind][name]
    read = parse_quantity(f"{value!r} {name}", kind)
    assert read == pytest.approx(value * scale, rel=1e-15, abs=0.0)
    written = format_quantity(read, kind, digits=17)
    assert parse_quantity(written, kind) == pytest.approx(read, rel=1e-15, abs=0.0)
    shown = format_quantity(read, kind)
    assert math.isclose(parse_quantity(shown, kind), read, rel_tol=5e-4)
