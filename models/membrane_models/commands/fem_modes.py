"""`membrane fem modes`: the lowest frequencies, beside their closed forms where one exists.

Each FEM mode's frequency (Hz) is printed with the closed form's (``fem_reference``: the i-th
lowest closed-form value beside the i-th lowest FEM mode, so a degenerate pair meets its
pair), their relative difference, and the closed form's indices; '-' where none exists.
"""

from __future__ import annotations

import argparse

from membrane_models import fem
from membrane_models.commands.fem_reference import Reference, closed_form
from membrane_models.commands.fem_setup import describe, tissue

__all__ = ["mode_table", "run_modes"]


def run_modes(args: argparse.Namespace) -> int:
    """The handler of ``membrane fem modes``."""
    item = tissue(args)
    system = fem.assemble(item.domain, item.model, item.supports)
    found = fem.modes(system, args.count)
    reference = closed_form(item, args.count)
    lines = describe(item, system)
    lines.append(f"closed form: {reference.title}" if reference else "closed form: none here")
    lines += mode_table([float(f) for f in found.frequency], reference)
    print("\n".join(lines))
    if args.plot is not None:
        from membrane_models.commands.fem_plots import plot_modes  # matplotlib

        shapes = system.vertex_values(found.shapes)
        plot_modes(args.plot, item.domain.mesh, shapes, [float(f) for f in found.frequency])
        print(f"plot: {args.plot}")
    return 0


def mode_table(frequencies: list[float], reference: Reference | None) -> list[str]:
    """One line per mode: FEM Hz, closed-form Hz, the relative difference, the indices."""
    known = reference.frequencies if reference else ()
    labels = reference.labels if reference else ()
    lines = [f"{'mode':>4}  {'FEM (Hz)':>12}  {'closed form (Hz)':>16}  {'difference':>10}"]
    for index, value in enumerate(frequencies):
        if index < len(known):
            exact = known[index]
            difference = f"{(value - exact) / exact:+.3%}"
            row = f"{exact:16.6g}  {difference:>10}  {labels[index]}"
        else:
            row = f"{'-':>16}  {'-':>10}"
        lines.append(f"{index + 1:>4}  {value:12.6g}  {row}")
    return lines
