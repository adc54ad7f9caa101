"""Quantities with units, as people type them: ``50mm``, ``1.5 MPa``, ``1109kg/m3``, ``20ms``.

``parse_quantity(text, kind)`` returns the value in SI (m, Pa, N, kg/m^3, N/m, N/m^3, s, Hz);
``format_quantity(value, kind)`` writes an SI value back in a readable unit (``0.003315`` m ->
``"3.315 mm"``). Bad input raises ``UnitError`` (a ``membrane_errors.UserError``: one line at
the command line, exit code 2), with a message that says what to type instead:

- a bare number for a dimensional quantity: ``--size 50: give a unit, e.g. 50mm`` (a bare 0 is
  accepted: zero is zero in every unit);
- a unit of another kind: ``--size 2kPa: kPa is a pressure, not a length; a length takes m,
  cm, mm, um``;
- an unknown unit: the accepted ones, and the one meant when only the case differs (``mpa``:
  did you mean MPa?). Units are case-sensitive: ``mPa`` is not ``MPa``;
- a number that is not finite (``inf``, ``nan``, ``1e999mm``).

Spellings: a space between number and unit is allowed; ``µ`` and ``μ`` may stand for ``u``;
powers may be written ``m3``, ``m^3`` or ``m³``.

Why a table and not a units library (pint, astropy.units): the commands need about thirty
units in eight kinds, a library would be a new dependency of a module that must import with
the core dependencies (the ``membrane`` command lists every command on a client-only install),
and a table is read in one screen. The kinds are fixed by what a command asks for, so a
library's dimensional algebra would go unused.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from types import MappingProxyType
from typing import Literal, get_args

from membrane_errors import UserError

__all__ = ["KINDS", "UNITS", "Kind", "UnitError", "format_quantity", "parse_quantity"]

Kind = Literal[
    "length", "pressure", "force", "density", "tension", "foundation", "time", "frequency"
]
KINDS: tuple[str, ...] = get_args(Kind)

# kind -> unit -> its size in SI as a power of ten (every unit here is one). Each kind's first
# unit is SI's own.
_EXPONENTS: Mapping[str, Mapping[str, int]] = {
    "length": {"m": 0, "cm": -2, "mm": -3, "um": -6},
    "pressure": {"Pa": 0, "kPa": 3, "MPa": 6, "GPa": 9},
    "force": {"N": 0, "mN": -3, "kN": 3},
    "density": {"kg/m3": 0, "g/cm3": 3},
    "tension": {"N/m": 0, "N/mm": 3},
    "foundation": {"N/m3": 0, "kPa/mm": 6},
    "time": {"s": 0, "ms": -3, "us": -6},
    "frequency": {"Hz": 0, "kHz": 3},
}
UNITS: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {kind: {unit: 10.0**e for unit, e in units.items()} for kind, units in _EXPONENTS.items()}
)
# What each kind's values are written in (ascending), and the unit a bare number's hint names.
_DISPLAY: Mapping[str, tuple[str, ...]] = {
    "length": ("um", "mm", "m"),
    "pressure": ("Pa", "kPa", "MPa", "GPa"),
    "force": ("mN", "N", "kN"),
    "density": ("kg/m3",),
    "tension": ("N/m",),
    "foundation": ("N/m3", "kPa/mm"),
    "time": ("us", "ms", "s"),
    "frequency": ("Hz", "kHz"),
}
_EXAMPLE: Mapping[str, str] = {
    "length": "mm",
    "pressure": "kPa",
    "force": "N",
    "density": "kg/m3",
    "tension": "N/m",
    "foundation": "kPa/mm",
    "time": "ms",
    "frequency": "Hz",
}
_ARTICLE = {
    "length": "a length",
    "pressure": "a pressure",
    "force": "a force",
    "density": "a density",
    "tension": "a tension",
    "foundation": "a foundation stiffness",
    "time": "a time",
    "frequency": "a frequency",
}
_NUMBER = re.compile(
    r"\s*(?P<number>[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan))"
    r"\s*(?P<unit>.*?)\s*",
    re.IGNORECASE,
)


class UnitError(UserError):
    """A quantity that cannot be read: no number, no unit, a unit of another kind, not finite."""


def parse_quantity(
    text: str, kind: str, *, name: str | None = None, default_unit: str | None = None
) -> float:
    """The value of ``text`` (a number and a unit of ``kind``) in SI.

    Args:
        text: e.g. ``"50mm"``, ``"1.5 MPa"``, ``"2e-3 m"``.
        kind: one of ``KINDS``.
        name: what the value is (a flag, ``"--size"``), to begin error messages with.
        default_unit: the unit of a bare number (None: a bare number other than 0 is refused).

    Raises:
        UnitError: see the module docstring.
    """
    units = _units_of(kind)
    label = f"{name} {text}" if name else repr(text)
    match = _NUMBER.fullmatch(text)
    if match is None:
        raise UnitError(f"{label}: not a number with a unit, e.g. 50{_EXAMPLE[kind]}")
    number, unit = float(match["number"]), _normalise(match["unit"])
    if not math.isfinite(number):
        raise UnitError(f"{label}: must be finite")
    if not unit:
        if default_unit is not None:
            unit = default_unit
        elif number == 0.0:
            return 0.0
        else:
            example = f"{match['number']}{_EXAMPLE[kind]}"
            raise UnitError(f"{label}: give a unit, e.g. {example}")
    if unit not in units:
        raise UnitError(f"{label}: {_unknown(unit, kind)}")
    value = _in_si(number, _EXPONENTS[kind][unit])
    if not math.isfinite(value):
        raise UnitError(f"{label}: must be finite")
    return value


def format_quantity(value: float, kind: str, digits: int = 4) -> str:
    """``value`` (SI) with ``digits`` significant digits in the largest of the kind's display
    units that keeps the number >= 1 (``0.003315`` m -> ``"3.315 mm"``; 0 in SI's unit)."""
    units = _units_of(kind)
    display = _DISPLAY[kind]
    chosen = display[0]
    for unit in display:
        if abs(value) >= units[unit] * (1.0 - 0.5 * 10.0**-digits):  # 999.96 -> 1 kPa
            chosen = unit
    if value == 0.0 or not math.isfinite(value):
        chosen = next(iter(units))
    shown = _in_si(value, -_EXPONENTS[kind][chosen])
    return f"{shown:.{digits}g} {chosen}"


def _units_of(kind: str) -> Mapping[str, float]:
    if kind not in UNITS:
        raise ValueError(f"unknown kind of quantity {kind!r}; known: {', '.join(KINDS)}")
    return UNITS[kind]


def _in_si(number: float, exponent: int) -> float:
    """``number * 10**exponent`` in one correctly rounded operation (``5 us`` is 5e-6 s
    exactly, where ``5 * 1e-6`` is not)."""
    return number * 10.0**exponent if exponent >= 0 else number / 10.0**-exponent


def _normalise(unit: str) -> str:
    """One spelling per unit: no spaces, ``u`` for micro, powers without ``^``."""
    unit = unit.replace(" ", "").replace("µ", "u").replace("μ", "u")
    return unit.replace("^", "").replace("³", "3").replace("²", "2")


def _unknown(unit: str, kind: str) -> str:
    """Why ``unit`` is not one of ``kind``'s, and what is."""
    accepted = f"{_ARTICLE[kind]} takes {', '.join(UNITS[kind])}"
    for other, units in UNITS.items():
        if other != kind and unit in units:
            return f"{unit} is {_ARTICLE[other]}, not {_ARTICLE[kind]}; {accepted}"
    near = [u for u in UNITS[kind] if u.lower() == unit.lower()]
    hint = f" (did you mean {near[0]}?)" if near else ""
    return f"unknown unit {unit!r}{hint}; {accepted}"
