"""The fem room's figures: every reference row on fine meshes, and the skin patch's timing.

1. Reference rows (plate: D = 1 N m, nu = 0.3, unit square or unit disk; membrane: c = 4 m/s):
   value on the finest mesh, its relative error, the mesh size h (longest edge), the free DOFs
   and the observed order between the two finest meshes.
2. The study's skin patch: a 50 mm square, clamped, E 1.5 MPa, nu 0.45, rho 1109 kg/m^3,
   h 3 mm. Wall time of mesh + assembly + the 100 lowest modes per mesh, the modes' worst error
   against a refined mesh, and the centre compliance w/P under a point load against a refined
   value (target: mesh + 100 modes under 10 s).

    python benchmarks/fem_figures.py            # about twenty seconds
    python benchmarks/fem_figures.py --quick    # coarser meshes, a few seconds
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
from scipy.special import jn_zeros

from membrane_models import fem

NU = 0.3
UNIT_PLATE = fem.Plate(12 * (1 - NU**2), NU, 1.0, 1.0)  # D = 1 N m, rho h = 1 kg/m^2
MEMBRANE = fem.Membrane(4.0, 0.25)
SKIN = fem.Plate(1.5e6, 0.45, 0.003, 1109.0)
SIDE = 0.05

Case = Callable[[float], tuple[float, fem.System]]  # size -> (value, system)


def _row(name: str, reference: float, case: Case, sizes: Sequence[float], tol: str) -> None:
    """One row. The order is the self-convergence order of the last three meshes (``s``: the
    references are rounded to 5 digits, below which an error against them stalls), or against
    the reference with two meshes (``r``)."""
    values, system, h = [], None, []
    for size in sizes:
        value, system = case(size)
        values.append(value)
        h.append(system.domain.size)
    assert system is not None
    if len(values) >= 3:
        steps = abs(values[-3] - values[-2]), abs(values[-2] - values[-1])
        order, kind = math.log(steps[0] / steps[1]) / math.log(h[-2] / h[-1]), "s"
    else:
        errors = [v / reference - 1 for v in values]
        order, kind = math.log(abs(errors[-2] / errors[-1])) / math.log(h[-2] / h[-1]), "r"
    print(
        f"{name:44s} {values[-1]:12.7g} {reference:12.7g} {values[-1] / reference - 1:+10.2e}"
        f" {h[-1]:8.4f} {system.free:7d} {order:6.2f}{kind}  {tol}"
    )


def _square(condition: str, load: str) -> Case:
    def case(size: float) -> tuple[float, fem.System]:
        system = fem.assemble(fem.rectangle(1.0, 1.0, size), UNIT_PLATE, condition)
        if load == "frequency":
            return float(fem.modes(system, 1).omega[0]), system
        f = (
            fem.point_load(system, 1.0, (0.5, 0.5))
            if load == "point"
            else fem.pressure_load(system, 1.0)
        )
        return float(fem.sample(system, fem.solve(system, f), (0.5, 0.5))), system

    return case


def _disk(condition: str, exact_frame: bool = True) -> Case:
    def case(size: float) -> tuple[float, fem.System]:
        system = fem.assemble(fem.disk(1.0, size), UNIT_PLATE, condition, exact_frame=exact_frame)
        u = fem.solve(system, fem.point_load(system, 1.0, (0.0, 0.0)))
        return float(fem.sample(system, u, (0.0, 0.0))), system

    return case


def _navier(pretension: float, foundation: float) -> tuple[float, Case]:
    plate = fem.Plate(UNIT_PLATE.youngs_modulus, NU, 1.0, 1.0, pretension, foundation)
    m = np.arange(1, 401, 2, dtype=float)[:, None]
    n = np.arange(1, 401, 2, dtype=float)[None, :]
    s = m**2 + (n / 0.8) ** 2
    amp = 16 / (math.pi**2 * m * n) / (math.pi**4 * s**2 + pretension * math.pi**2 * s + foundation)
    exact = float((amp * np.sin(m * math.pi / 2) * np.sin(n * math.pi / 2)).sum())

    def case(size: float) -> tuple[float, fem.System]:
        system = fem.assemble(fem.rectangle(1.0, 0.8, size), plate, "simply_supported")
        u = fem.solve(system, fem.pressure_load(system, 1.0))
        return float(fem.sample(system, u, (0.5, 0.4))), system

    return exact, case


def _ellipse(size: float) -> tuple[float, fem.System]:
    system = fem.assemble(fem.ellipse(1.0, 0.6, size), UNIT_PLATE, "clamped")
    u = fem.solve(system, fem.pressure_load(system, 1.0))
    return float(fem.sample(system, u, (0.0, 0.0))), system


def _membrane(shape: str, index: int) -> tuple[float, Case]:
    c = MEMBRANE.wave_speed
    if shape == "rectangle":
        omegas = [c * math.pi * math.hypot(m, n / 0.7) for m in range(1, 8) for n in range(1, 8)]
    else:
        zeros = [z for k in range(4) for z in jn_zeros(k, 3) for _ in range(1 if k == 0 else 2)]
        omegas = [c * z / 0.5 for z in zeros]
    exact = float(np.sort(omegas)[index])

    def case(size: float) -> tuple[float, fem.System]:
        domain = fem.rectangle(1.0, 0.7, size) if shape == "rectangle" else fem.disk(0.5, size)
        system = fem.assemble(domain, MEMBRANE, "clamped")
        return float(fem.modes(system, index + 1).omega[index]), system

    return exact, case


def reference_rows(quick: bool) -> None:
    squares = [1 / 8, 1 / 16] if quick else [1 / 8, 1 / 16, 1 / 32]
    disks = [0.25, 0.13] if quick else [0.25, 0.13, 0.066]
    print(
        f"{'row':44s} {'value':>12s} {'reference':>12s} {'rel. error':>10s} {'h':>8s}"
        f" {'DOFs':>7s} {'order':>7s}  asked"
    )
    for condition, point, pressure in [
        ("clamped", 0.005612, 0.0012653),
        ("simply_supported", 0.011601, 0.0040624),
    ]:
        _row(
            f"square {condition}: point w/(P a^2/D)",
            point,
            _square(condition, "point"),
            squares,
            "1%",
        )
        _row(
            f"square {condition}: uniform w/(q a^4/D)",
            pressure,
            _square(condition, "pressure"),
            squares,
            "1%",
        )
    _row(
        "square clamped: omega a^2 sqrt(rho h/D)",
        35.985,
        _square("clamped", "frequency"),
        squares,
        "0.5%",
    )
    _row("disk clamped: point w/(P R^2/D)", 1 / (16 * math.pi), _disk("clamped"), disks, "1%")
    ss = (3 + NU) / (1 + NU) / (16 * math.pi)
    _row("disk simply supported: point w/(P R^2/D)", ss, _disk("simply_supported"), disks, "1%")
    _row(
        "  the same in the polygon frame (Babuska)",
        ss,
        _disk("simply_supported", False),
        disks,
        "off",
    )
    for pretension, foundation in [(0.0, 400.0), (30.0, 0.0), (30.0, 400.0)]:
        exact, case = _navier(pretension, foundation)
        _row(
            f"SS 1 x 0.8 Navier, T {pretension:g}, k {foundation:g}",
            exact,
            case,
            [1 / 4, 1 / 8],
            "0.5%",
        )
    try:
        w0 = 1 / (24 + 16 / 0.36 + 24 / 0.6**4)
        _row("ellipse 1 x 0.6 clamped, uniform (gmsh)", w0, _ellipse, [0.2, 0.1, 0.05], "1%")
    except fem.MissingMesher as error:
        print(f"ellipse: skipped ({error})")
    for shape, sizes in [
        ("rectangle", [0.2, 0.1, 0.05]),
        ("disk", [0.25 * 0.5, 0.13 * 0.5, 0.066 * 0.5]),
    ]:
        for index in (0, 5):
            exact, case = _membrane(shape, index)
            _row(f"membrane {shape}: omega_{index + 1} (rad/s)", exact, case, sizes, "0.1%")


def skin_patch(quick: bool) -> None:
    print("\nskin patch: 50 mm square, clamped, E 1.5 MPa, nu 0.45, rho 1109 kg/m^3, h 3 mm")
    reference_n = 32 if quick else 48
    fine = fem.assemble(fem.rectangle(SIDE, SIDE, SIDE / reference_n), SKIN, "clamped")
    fine_modes = fem.modes(fine, 100).omega
    half = fem.assemble(fem.rectangle(SIDE, SIDE, 2 * SIDE / reference_n), SKIN, "clamped")
    centre = (SIDE / 2, SIDE / 2)
    w_fine, w_half = (
        float(fem.sample(s, fem.solve(s, fem.point_load(s, 1.0, centre)), centre))
        for s in (fine, half)
    )
    fine_w = w_fine + (w_fine - w_half) / 3  # Richardson, order 2
    series = SIDE**2 / SKIN.rigidity * 0.005612
    print(
        f"refined w/P: {w_fine:.6e} m/N on {reference_n} x {reference_n}, {fine_w:.6e} extrapolated"
        f" (0.005612 a^2/D = {series:.6e}); modes against {reference_n} x {reference_n}"
    )
    print(
        f"{'mesh':>7s} {'DOFs':>6s} {'mesh s':>7s} {'assemble s':>10s} {'100 modes s':>11s}"
        f" {'total s':>8s} {'f1 Hz':>8s} {'f100 Hz':>9s} {'worst mode err':>14s}"
        f" {'w/P m/N':>12s} {'w/P err':>9s}"
    )
    for n in [10, 16] if quick else [10, 16, 20, 24]:
        start = time.perf_counter()
        domain = fem.rectangle(SIDE, SIDE, SIDE / n)
        meshed = time.perf_counter()
        system = fem.assemble(domain, SKIN, "clamped")
        assembled = time.perf_counter()
        modes = fem.modes(system, 100)
        solved = time.perf_counter()
        u = fem.solve(system, fem.point_load(system, 1.0, (SIDE / 2, SIDE / 2)))
        w = float(fem.sample(system, u, (SIDE / 2, SIDE / 2)))
        worst = float(np.abs(modes.omega / fine_modes - 1).max())
        print(
            f"{n:3d}x{n:<3d} {system.free:6d} {meshed - start:7.3f} {assembled - meshed:10.3f}"
            f" {solved - assembled:11.3f} {solved - start:8.3f} {modes.frequency[0]:8.2f}"
            f" {modes.frequency[99]:9.1f} {worst:14.2e} {w:12.5e} {w / fine_w - 1:+9.2e}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarser meshes")
    args = parser.parse_args()
    reference_rows(args.quick)
    skin_patch(args.quick)


if __name__ == "__main__":
    main()
