"""The `membrane fem` command: a plate or a membrane on a mesh, from the command line.

``membrane fem static`` (the deflection and stress under a load), ``modes`` (frequencies beside
their closed forms) and ``transient`` (the live engine stepped under a load). Quantities take
units (``--size 50mm --E 1.5MPa``, ``membrane_models.physical.units``).

This module imports with the core dependencies only (the dispatcher lists every command even
on a client-only install); the fem room (scikit-fem, scipy) and matplotlib are imported inside
the handlers, by ``fem_setup``, ``fem_static``, ``fem_modes``, ``fem_transient`` and
``fem_plots``.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from membrane_cli.arguments import bounded_float, bounded_int

__all__ = ["SHAPES", "add_fem"]

SHAPES = ("square", "rectangle", "disk", "ellipse", "polygon", "mesh")
MAX_MODES = 2000
# A value that starts like a negative number is a value, not an option: argparse's own test
# takes "-5" but not "-5,0" (--at) or "-3mm" (which the units check then refuses with its flag).
_NEGATIVE_VALUE = re.compile(r"^-\.?\d")

_DESCRIPTION = """\
A Kirchhoff plate (Argyris triangles) or a membrane (P2 triangles) on a mesh, in SI inside and
in the units you type outside: every dimensional value takes a unit (50mm, 1.5MPa, 1N, 20ms;
a bare number is refused, except 0). --at, --vertices and --hole are in mm.

Shapes: square and rectangle have their lower-left corner at the origin; disk and ellipse are
centred on it; polygon takes its vertices; mesh reads a .msh or .vtk file (coordinates in
metres, boundary parts from its named line groups). Defaults are the study's skin patch:
E 1.5MPa, nu 0.45, thickness 3mm, density 1109kg/m3, clamped."""

_STATIC_EPILOG = """\
examples:
  membrane fem static --shape square --size 50mm --thickness 3mm --E 1.5MPa --nu 0.45 --load 1N
  membrane fem static --size 50mm --load 2N --at 20,25 --tool-radius 5mm --plot w.png
  membrane fem static --shape disk --size 40mm --pressure 1kPa --supports simply_supported
  membrane fem static --shape polygon --vertices "0,0;40,0;40,30;0,30" --hole "15,10;25,10;25,20"
      --load 1N --at 8,15

The stress is von Mises at the surface (bending plus the pre-tension's membrane stress). Under
a point load it diverges like log(1/r) at the load, so it is read at r = h from it; with
--tool-radius it is read under the patch's centre."""

_MODES_EPILOG = """\
examples:
  membrane fem modes --shape disk --size 40mm --thickness 3mm --E 1.5MPa --nu 0.45
  membrane fem modes --shape square --size 50mm --supports simply_supported --tension 10N/m
  membrane fem modes --model membrane --tension 50N/m --shape rectangle --size 40mmx30mm

Closed forms (where one exists): a fixed membrane rectangle or disk; a simply supported
rectangular plate (with pre-tension and foundation); a clamped disk plate (Bessel roots); a
clamped square plate's first mode (35.985/a^2 sqrt(D/rho h)). A foundation k shifts a plate's
omega^2 by k/(rho h)."""

_TRANSIENT_EPILOG = """\
examples:
  membrane fem transient --size 50mm --load 1N --duration 20ms
  membrane fem transient --size 50mm --load 1N --ramp 5ms --damping 0.05 --plot w_t.png

The live engine (the modal stepper over the model's tabulated FEM modes, with the static
correction of the modes not stepped) under a Gaussian footprint of --tool-radius, applied
suddenly (--ramp 0ms) or ramped linearly. The tables are kept in --cache-dir (default: the
user cache, $MEMBRANE_CACHE_DIR/fem if set) and read back in milliseconds next time."""


def add_fem(subparsers: argparse._SubParsersAction) -> None:
    """Register ``membrane fem`` and its subcommands."""
    parser = subparsers.add_parser(
        "fem",
        help="a plate or membrane on a mesh: static deflection, modes, transient",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.set_defaults(handler=lambda args: _usage(parser))
    commands = parser.add_subparsers(title="subcommands", dest="fem_command", metavar="SUBCOMMAND")
    common = _common_options()
    static = _subparser(
        commands, common, "static", "deflection, stiffness and stress under a load", _STATIC_EPILOG
    )
    _load_options(static, transient=False)
    static.add_argument(
        "--pressure", metavar="PRESSURE", help="a uniform pressure instead of --load, e.g. 1kPa"
    )
    static.add_argument(
        "--nonlinear",
        nargs="?",
        const="held",
        choices=("held", "sliding"),
        help="also the large-deflection (von Karman) plate, its edges held (default) or "
        "sliding in their plane, side by side with the linear one",
    )
    static.set_defaults(handler=_run_static)

    modes = _subparser(
        commands, common, "modes", "frequencies beside their closed forms", _MODES_EPILOG
    )
    modes.add_argument(
        "--count",
        metavar="N",
        type=bounded_int(1, MAX_MODES),
        default=10,
        help="modes to find (default 10)",
    )
    modes.set_defaults(handler=_run_modes)

    transient = _subparser(
        commands, common, "transient", "the live engine under a load", _TRANSIENT_EPILOG
    )
    _load_options(transient, transient=True)
    transient.add_argument(
        "--duration", metavar="TIME", default="20ms", help="time stepped (default 20ms)"
    )
    transient.add_argument(
        "--dt", metavar="TIME", default="0.05ms", help="the step (default 0.05ms)"
    )
    transient.add_argument(
        "--ramp",
        metavar="TIME",
        default="0ms",
        help="ramp the load up over this time (default 0ms: sudden)",
    )
    transient.add_argument(
        "--damping",
        metavar="ZETA",
        type=bounded_float(0.0),
        default=0.0,
        help="modal damping ratio zeta (default 0)",
    )
    transient.add_argument(
        "--count",
        metavar="N",
        type=bounded_int(1, MAX_MODES),
        default=100,
        help="modes stepped (default 100)",
    )
    transient.add_argument(
        "--cache-dir",
        metavar="DIR",
        type=Path,
        help="where the live tables are kept (default: the user cache)",
    )
    transient.set_defaults(handler=_run_transient)


def _subparser(
    commands: argparse._SubParsersAction,
    common: argparse.ArgumentParser,
    name: str,
    summary: str,
    epilog: str,
) -> argparse.ArgumentParser:
    parser: argparse.ArgumentParser = commands.add_parser(
        name,
        parents=[common],
        help=summary,
        description=f"{summary[0].upper()}{summary[1:]}.\n\n{_DESCRIPTION}",
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser._negative_number_matcher = _NEGATIVE_VALUE
    return parser


def _common_options() -> argparse.ArgumentParser:
    """The options every subcommand takes: the shape, the mesh, the model, the supports."""
    common = argparse.ArgumentParser(add_help=False)
    shape = common.add_argument_group("shape and mesh")
    shape.add_argument("--shape", choices=SHAPES, default="square", help="(default square)")
    shape.add_argument(
        "--size",
        metavar="SIZE",
        help="square: side (50mm); rectangle, ellipse: 40mmx30mm; disk: diameter",
    )
    shape.add_argument("--vertices", metavar='"X,Y;..."', help='polygon: "x,y;x,y;..." in mm')
    shape.add_argument(
        "--hole",
        metavar='"X,Y;..."',
        action="append",
        default=[],
        help="polygon: a hole's vertices, as --vertices (repeatable)",
    )
    shape.add_argument(
        "--mesh", metavar="FILE", type=Path, help="mesh: a .msh or .vtk file (metres)"
    )
    shape.add_argument(
        "--element-size",
        metavar="LENGTH",
        help="target edge length (default: the side, the "
        "largest axis or extent /20; a disk's diameter /15)",
    )
    model = common.add_argument_group("model")
    model.add_argument(
        "--model", choices=("plate", "membrane"), default="plate", help="(default plate)"
    )
    model.add_argument(
        "--E",
        dest="youngs_modulus",
        metavar="PRESSURE",
        default="1.5MPa",
        help="Young's modulus (default 1.5MPa)",
    )
    model.add_argument(
        "--nu",
        dest="poisson",
        metavar="NU",
        type=bounded_float(),
        default=0.45,
        help="Poisson's ratio (default 0.45)",
    )
    model.add_argument("--thickness", metavar="LENGTH", default="3mm", help="(default 3mm)")
    model.add_argument(
        "--density", metavar="DENSITY", default="1109kg/m3", help="(default 1109kg/m3)"
    )
    model.add_argument(
        "--tension", metavar="TENSION", help="a membrane's tension, a plate's pre-tension (N/m)"
    )
    model.add_argument(
        "--foundation", metavar="STIFFNESS", help="a plate's Winkler foundation (N/m3, kPa/mm)"
    )
    model.add_argument(
        "--supports",
        metavar="SUPPORTS",
        default="clamped",
        help="clamped, simply_supported or free, or PART=CONDITION,... "
        "(parts: left, right, bottom, top; rim; outer, hole0, ...)",
    )
    common.add_argument(
        "--plot",
        metavar="FILE.png",
        type=Path,
        help="draw the result: static the deflection map, modes the first shapes, transient "
        "the deflection under the load against time",
    )
    return common


def _load_options(parser: argparse.ArgumentParser, transient: bool) -> None:
    load = parser.add_argument_group("load")
    load.add_argument("--load", metavar="FORCE", help="the force (default 1N)")
    load.add_argument("--at", metavar="X,Y", help="where, X,Y in mm (default: the mesh's centroid)")
    if transient:
        load.add_argument(
            "--tool-radius",
            metavar="LENGTH",
            default="2.5mm",
            help="the Gaussian footprint's radius (default 2.5mm)",
        )
    else:
        load.add_argument(
            "--tool-radius",
            metavar="LENGTH",
            help="spread the load uniformly over a disk, e.g. 5mm",
        )


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _run_static(args: argparse.Namespace) -> int:
    from membrane_models.commands.fem_static import run_static  # scikit-fem, scipy

    return run_static(args)


def _run_modes(args: argparse.Namespace) -> int:
    from membrane_models.commands.fem_modes import run_modes  # scikit-fem, scipy

    return run_modes(args)


def _run_transient(args: argparse.Namespace) -> int:
    from membrane_models.commands.fem_transient import run_transient  # scikit-fem, scipy

    return run_transient(args)
