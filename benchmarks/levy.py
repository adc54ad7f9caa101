"""The von Karman plate against Levy's clamped square under uniform pressure (docs/NONLINEAR.md).

    python benchmarks/levy.py [--quick]

Levy (1942, NACA Report 740 / TN 847, Table 5) solved the clamped square plate under uniform
pressure q by double Fourier series, nu = 0.316, each edge's in-plane displacement normal to it
held and the tangential one free: ``fem.solve_nonlinear``'s "sliding". His centre deflections
w0 / h at nine loads Q = q a^4 / (E h^4) are below (``LEVY``); the values are as transcribed in
public benchmark code (two copies in the code index agree), not read from the report's scan.

In von Karman's theory w0 / h depends on Q and nu alone, so any a / h gives the same figures;
a = 1 m, h = 10 mm here. Printed: the FEM's w0 / h on two meshes, Levy's, the difference, and
the linear plate's (w0 = 0.00126 q a^4 / D, the double series of Timoshenko and
Woinowsky-Krieger, Table 35), from which Levy's first point departs by 2.4 % already.

Each load is solved from the flat plate (adaptive increments).
"""

from __future__ import annotations

import argparse
import time

from membrane_models import fem
from membrane_models.fem.nonlinear import solve_nonlinear

A, H, NU = 1.0, 0.01, 0.316
PLATE = fem.Plate(youngs_modulus=1.0e6, poisson=NU, thickness=H, density=1000.0)
# Levy, NACA Report 740, Table 5: (q a^4 / (E h^4), w0 / h)
LEVY = (
    (17.79, 0.237), (38.3, 0.471), (63.4, 0.695), (95.0, 0.912), (134.9, 1.121),
    (184.0, 1.323), (245.0, 1.521), (318.0, 1.714), (402.0, 1.902),
)  # fmt: skip
LINEAR_COEFFICIENT = 0.00126  # w0 = 0.00126 q a^4 / D, clamped square


def centre_deflection(system: fem.System, load_number: float) -> float:
    """The FEM's w0 / h at q a^4 / (E h^4) = ``load_number``."""
    q = load_number * PLATE.youngs_modulus * H**4 / A**4
    state = solve_nonlinear(system, fem.pressure_load(system, q), "sliding")
    return abs(fem.sample(system, state.w, [(A / 2, A / 2)])[0]) / H


def linear_deflection(load_number: float) -> float:
    """The linear plate's w0 / h."""
    flexural = PLATE.youngs_modulus * H**3 / (12 * (1 - NU**2))
    q = load_number * PLATE.youngs_modulus * H**4 / A**4
    return LINEAR_COEFFICIENT * q * A**4 / flexural / H


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the coarser mesh only")
    args = parser.parse_args()
    sizes = (A / 8,) if args.quick else (A / 8, A / 16)
    systems = []
    for size in sizes:
        began = time.perf_counter()
        system = fem.assemble(fem.rectangle(A, A, size), PLATE, "clamped")
        systems.append(system)
        print(f"mesh: edge a / {A / size:.0f}, {system.dofs} DOFs (w), assembled in "
              f"{time.perf_counter() - began:.1f} s")  # fmt: skip
    heads = " | ".join(f"FEM a/{A / s:.0f}" for s in sizes)
    print(f"\n| Q = q a^4 / (E h^4) | Levy w0/h | {heads} | FEM - Levy | linear w0/h |")
    print("| --- | --- | " + " --- |" * len(sizes) + " --- | --- |")
    for load_number, levy in LEVY:
        values = [centre_deflection(system, load_number) for system in systems]
        cells = " | ".join(f"{v:.4f}" for v in values)
        difference = 100 * (values[-1] - levy) / levy
        print(f"| {load_number:g} | {levy:.3f} | {cells} | {difference:+.2f} % | "
              f"{linear_deflection(load_number):.4f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
