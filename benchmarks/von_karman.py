"""The von Karman plate's figures (docs/NONLINEAR.md).

    python benchmarks/von_karman.py

1. The clamped circular plate under uniform pressure, edge held in its plane (nu = 0.3,
   a / h = 100), against the one-term solution of Timoshenko and Woinowsky-Krieger,
   w0/h + 0.488 (w0/h)^3 = q a^4 / (64 D h), on three refinements of the disk: the centre
   deflection, the one-term value from the mesh's own linear deflection (so that the polygonal
   rim's error cancels) and the departure; the observed order of the nonlinear centre
   deflection over the refinements.
2. The study's skin patch (50 mm, clamped, E 1.5 MPa, nu 0.45, h 3 mm) under 1 N at its
   centre: linear against nonlinear, edges held or sliding in their plane, two meshes.
"""

from __future__ import annotations

import math
import sys
import time

from scipy.optimize import brentq

from membrane_models import fem
from membrane_models.fem.nonlinear import solve_nonlinear


def disk_rows() -> None:
    a, h = 0.05, 0.0005
    plate = fem.Plate(youngs_modulus=1.0e6, poisson=0.3, thickness=h, density=1000.0)
    print("| mesh (DOFs w + u) | one-term w0/h | FEM w0/h | one-term from the mesh | departure |")
    print("| --- | --- | --- | --- | --- |")
    centres: dict[float, list[float]] = {0.5: [], 1.0: []}
    for size in (a / 1.5, a / 2.5, a / 5):
        system = fem.assemble(fem.disk(a, size), plate, "clamped")
        for target in centres:
            q = (target + 0.488 * target**3) * 64 * plate.rigidity * h / a**4
            load = fem.pressure_load(system, q)
            linear = fem.sample(system, fem.solve(system, load), [(0.0, 0.0)])[0] / h
            one_term = brentq(lambda x, s=linear: x + 0.488 * x**3 - s, 0.0, linear)
            began = time.perf_counter()
            state = solve_nonlinear(system, load, "held")
            w0 = fem.sample(system, state.w, [(0.0, 0.0)])[0] / h
            centres[target].append(w0)
            print(
                f"| {system.dofs} + {state.inplane_basis.N} | {target:g} | {w0:.5f} "
                f"| {one_term:.5f} | {100 * (w0 / one_term - 1):+.2f} % "
                f"({time.perf_counter() - began:.0f} s) |",
                flush=True,
            )
    for target, values in centres.items():
        order = math.log2(abs(values[1] - values[0]) / abs(values[2] - values[1]))
        print(f"observed order of w0 at w0/h = {target:g} (mesh halved each time): {order:.2f}")


def patch_rows() -> None:
    plate = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
    print("\n| mesh | DOFs | linear w0 (mm) | held (mm) | sliding (mm) |")
    print("| --- | --- | --- | --- | --- |")
    for size in (0.05 / 8, 0.05 / 12):
        system = fem.assemble(fem.rectangle(0.05, 0.05, size), plate, "clamped")
        load = fem.point_load(system, -1.0, (0.025, 0.025))
        at = [(0.025, 0.025)]
        linear = fem.sample(system, fem.solve(system, load), at)[0]
        held = fem.sample(system, solve_nonlinear(system, load, "held").w, at)[0]
        sliding = fem.sample(system, solve_nonlinear(system, load, "sliding").w, at)[0]
        print(
            f"| {size * 1e3:.2f} mm | {system.dofs} | {-linear * 1e3:.4f} | {-held * 1e3:.4f} "
            f"| {-sliding * 1e3:.4f} |",
            flush=True,
        )


def main() -> int:
    disk_rows()
    patch_rows()
    return 0


if __name__ == "__main__":
    sys.exit(main())
