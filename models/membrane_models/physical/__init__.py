"""Physical quantities for people: numbers with units, read from and written for the command line.

``units``: ``parse_quantity("50mm", "length") == 0.05`` (SI), ``format_quantity(0.05,
"length") == "50 mm"``. Imports the standard library only: every command may use it, even on a
client-only install.
"""

from membrane_models.physical.units import (
    KINDS,
    UNITS,
    Kind,
    UnitError,
    format_quantity,
    parse_quantity,
)

__all__ = ["KINDS", "UNITS", "Kind", "UnitError", "format_quantity", "parse_quantity"]
