"""`membrane fem static`: the deflection, stiffness and surface stress under one load.

The load is a point force (``--load`` at ``--at``), the same force spread uniformly over a
disk (``--tool-radius``) or a uniform pressure (``--pressure``). The stress is von Mises at
the surface (``fem.surface_stress``: bending plus the pre-tension's membrane stress): under a
point load the bending moment grows like log(1/r) towards the load, so the stress at the load
point is infinite and is read at r = h from it, where thin-plate theory stops applying; under
a patch it is read at the patch's centre, under a pressure at ``--at``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_cli.arguments import UsageError
from membrane_models import fem
from membrane_models.commands.fem_setup import (
    Tissue,
    describe,
    load_point,
    millimetres,
    positive,
    tissue,
)
from membrane_models.physical.units import format_quantity, parse_quantity

__all__ = ["THIN_LIMIT", "Loading", "run_static"]

FloatArray = NDArray[np.float64]
THIN_LIMIT = 0.2  # warn when w > 0.2 h: linear Kirchhoff theory assumes w << h
_DIRECTIONS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))  # where r = h is read


@dataclass(frozen=True)
class Loading:
    """What presses on the tissue.

    Attributes:
        kind: "point", "patch" or "pressure".
        force: N (a pressure: its total, q times the area).
        at: where the deflection (and a patch's stress) is read, (x, y) m.
        radius: a patch's radius (m), else 0.
        pressure: Pa, for "pressure", else 0.
    """

    kind: str
    force: float
    at: FloatArray
    radius: float = 0.0
    pressure: float = 0.0

    def words(self) -> str:
        where = f"at {millimetres(self.at)}"
        if self.kind == "pressure":
            area = f"{self.force / self.pressure * 1e6:.4g} mm2" if self.pressure else ""
            return f"uniform pressure {format_quantity(self.pressure, 'pressure')} over {area}"
        force = format_quantity(self.force, "force")
        if self.kind == "patch":
            disk = f"a {format_quantity(self.radius, 'length')} radius disk"
            return f"{force} spread uniformly over {disk} {where}"
        return f"{force} point load {where}"

    def vector(self, system: fem.System) -> FloatArray:
        if self.kind == "pressure":
            return fem.pressure_load(system, self.pressure)
        if self.kind == "patch":
            return fem.patch_load(system, self.force, self.at, self.radius)
        return fem.point_load(system, self.force, self.at)


def run_static(args: argparse.Namespace) -> int:
    """The handler of ``membrane fem static``."""
    item = tissue(args)
    loading = _loading(args, item.domain)
    system = fem.assemble(item.domain, item.model, item.supports)
    u = fem.solve(system, _vector(loading, system))
    w_at = float(fem.sample(system, u, loading.at))
    peak, peak_at = _peak(system, u, w_at, loading.at)
    lines = [*describe(item, system), f"load: {loading.words()}"]
    what = "the load" if loading.kind != "pressure" else millimetres(loading.at)
    lines.append(f"deflection at {what}: {w_at * 1e3:.4g} mm")
    lines.append(f"peak deflection: {peak * 1e3:.4g} mm at {millimetres(peak_at)}")
    lines.append(_stiffness(loading, w_at))
    lines.append(_stress(item, system, u, loading))
    if args.nonlinear is not None:
        lines += _nonlinear(item, system, u, loading, args.nonlinear)
    print("\n".join(lines))
    if args.nonlinear is None:
        _warn(item, loading, peak)
    if args.plot is not None:
        from membrane_models.commands.fem_plots import plot_deflection  # matplotlib

        w = system.vertex_values(u)
        plot_deflection(
            args.plot, item.domain.mesh, w, loading.at, f"{item.label}: {loading.words()}"
        )
        print(f"plot: {args.plot}")
    return 0


def _loading(args: argparse.Namespace, domain: fem.Domain) -> Loading:
    at = load_point(args, domain)
    if args.pressure is not None:
        if args.load is not None or args.tool_radius is not None:
            given = "--load" if args.load is not None else "--tool-radius"
            raise UsageError(f"--pressure is a uniform load: it takes no {given}")
        pressure = parse_quantity(args.pressure, "pressure", name="--pressure")
        if pressure == 0.0:
            raise UsageError("--pressure 0: a zero pressure deflects nothing")
        return Loading("pressure", pressure * domain.area, at, pressure=pressure)
    force = parse_quantity(args.load or "1N", "force", name="--load")
    if force == 0.0:
        raise UsageError("--load 0: a zero load deflects nothing")
    if args.tool_radius is None:
        return Loading("point", force, at)
    radius = positive(args.tool_radius, "length", "--tool-radius")
    return Loading("patch", force, at, radius=radius)


def _vector(loading: Loading, system: fem.System) -> FloatArray:
    try:
        return loading.vector(system)
    except fem.OutsideDomain:
        if loading.kind != "patch":
            raise
        where = f"the patch at {millimetres(loading.at)}"
        raise UsageError(
            f"--tool-radius {format_quantity(loading.radius, 'length')}: {where} "
            "reaches off the mesh"
        ) from None


def _peak(
    system: fem.System, u: FloatArray, w_at: float, at: FloatArray
) -> tuple[float, FloatArray]:
    """The largest |w| over the vertices and the load point, signed, and where."""
    w = system.vertex_values(u)
    index = int(np.argmax(np.abs(w)))
    if abs(w_at) >= abs(w[index]):
        return w_at, at
    return float(w[index]), np.asarray(system.domain.mesh.p[:, index], dtype=np.float64)


def _stiffness(loading: Loading, w_at: float) -> str:
    if loading.kind == "pressure":
        return f"stiffness: {loading.force / w_at / 1e3:.4g} N/mm (total force q A / deflection)"
    return f"stiffness: {loading.force / w_at / 1e3:.4g} N/mm"


def _stress(item: Tissue, system: fem.System, u: FloatArray, loading: Loading) -> str:
    if not isinstance(item.model, fem.Plate):
        return "stress: - (a membrane carries its tension only: no bending stress)"
    where = _stress_point(item, system, loading)
    if where is None:
        return "stress: - (no point r = h from the load lies on the mesh)"
    point, words = where
    stress = fem.surface_stress(system, u, point).von_mises
    return f"stress: {_kpa(stress)} at the surface (bending + pre-stress) {words}"


def _stress_point(
    item: Tissue, system: fem.System, loading: Loading
) -> tuple[FloatArray, str] | None:
    """Where the stress is read, and its words: under a patch's centre, at a pressure's
    point, at r = h from a point load (module docstring); None when no such point is on the
    mesh."""
    if loading.kind != "point":
        words = "under the patch's centre" if loading.kind == "patch" else "at the point"
        return loading.at, words
    assert isinstance(item.model, fem.Plate)
    h = item.model.thickness
    for direction in _DIRECTIONS:
        point = loading.at + h * np.asarray(direction)
        try:
            fem.sample(system, np.zeros(system.dofs), point)
        except fem.OutsideDomain:
            continue
        return point, (
            f"at r = h = {format_quantity(h, 'length')} from the load: under a point load the "
            "peak stress diverges like log(1/r), so it is read where thin-plate theory ends"
        )
    return None


def _nonlinear(
    item: Tissue, system: fem.System, u: FloatArray, loading: Loading, inplane: str
) -> list[str]:
    """The von Karman plate beside the linear one: deflection, stiffness, stress."""
    if not isinstance(item.model, fem.Plate):
        raise UsageError("--nonlinear is a plate's large deflection: the model is a membrane")
    state = fem.solve_nonlinear(system, _vector(loading, system), inplane=inplane)
    w_linear = float(fem.sample(system, u, loading.at))
    w_large = float(fem.sample(system, state.w, loading.at))
    rows = [
        ("deflection (mm)", f"{w_linear * 1e3:.4g}", f"{w_large * 1e3:.4g}"),
        ("stiffness (N/mm)", f"{loading.force / w_linear / 1e3:.4g}",
         f"{loading.force / w_large / 1e3:.4g}"),
    ]  # fmt: skip
    where = _stress_point(item, system, loading)
    if where is not None:
        point, _ = where
        linear = fem.surface_stress(system, u, point).von_mises
        membrane = fem.membrane_force(system, state, point)
        large = fem.surface_stress(system, state.w, point, membrane).von_mises
        rows.append(("stress (kPa von Mises)", f"{linear / 1e3:.4g}", f"{large / 1e3:.4g}"))
    header = ("", "linear", f"nonlinear (edges {inplane} in their plane)")
    widths = [max(len(row[i]) for row in [header, *rows]) + 2 for i in range(3)]
    table = ["".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip()
             for row in [header, *rows]]  # fmt: skip
    note = (
        f"von Karman plate: {state.increments} load increments, {state.iterations} Newton "
        "iterations; the stress adds the stretch's membrane force to the bending"
    )
    return ["", *table, note]


def _kpa(stress: float) -> str:
    return f"{stress / 1e3:.4g} kPa von Mises"


def _warn(item: Tissue, loading: Loading, peak: float) -> None:
    model = item.model
    if isinstance(model, fem.Plate) and abs(peak) > THIN_LIMIT * model.thickness:
        ratio = abs(peak) / model.thickness
        print(
            f"membrane fem static: warning: the peak deflection is {ratio:.0%} of the thickness; "
            "linear Kirchhoff theory assumes w << h (a real plate this bent is stiffer)",
            file=sys.stderr,
        )
    if isinstance(model, fem.Membrane) and loading.kind == "point":
        print(
            "membrane fem static: warning: a membrane's deflection under a point load is "
            "log-singular: it depends on the mesh (spread the load with --tool-radius)",
            file=sys.stderr,
        )
