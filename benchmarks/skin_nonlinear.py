"""The study's skin patch under 0.05 to 1 N, linear and nonlinear (docs/SKIN.md, table 9).

    python benchmarks/skin_nonlinear.py [--size 0.0025]

The 50 mm square patch (E 1.5 MPa, nu 0.45, h 3 mm) on Argyris triangles of ``--size`` m,
clamped or simply supported, its edges held in their plane in the nonlinear runs (the
immovable edge of the large-deflection tables), under a point force or a 5 mm patch (the
uniform pressure over the tool's disk: table 8's loads) at its centre: the centre deflection of
the linear Kirchhoff plate (``fem.solve``) and of the von Karman plate (``fem.solve_nonlinear``),
and the nonlinear stiffening (linear over nonlinear deflection).
"""

from __future__ import annotations

import argparse
import time

from membrane_models import fem
from membrane_models.fem.nonlinear import solve_nonlinear

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
CENTRE = (0.025, 0.025)
FORCES = (0.05, 0.1, 0.25, 0.5, 1.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=0.0025)
    args = parser.parse_args()
    header = "| supports | load | F (N) | linear w (mm) | w / h | nonlinear w (mm) |"
    print(header + " linear / nonlinear |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    began = time.perf_counter()
    for supports in ("clamped", "simply_supported"):
        system = fem.assemble(fem.rectangle(0.05, 0.05, args.size), SKIN, supports)
        for load_name in ("point", "5 mm patch"):
            for force in FORCES:
                if load_name == "point":
                    load = fem.point_load(system, -force, CENTRE)
                else:
                    load = fem.patch_load(system, -force, CENTRE, 0.005)
                linear = -fem.sample(system, fem.solve(system, load), [CENTRE])[0]
                state = solve_nonlinear(system, load, "held")
                nonlinear = -fem.sample(system, state.w, [CENTRE])[0]
                name = supports.replace("_", " ")
                print(f"| {name} | {load_name} | {force:g} | {linear * 1e3:.4f} | "
                      f"{linear / SKIN.thickness:.3f} | {nonlinear * 1e3:.4f} | "
                      f"{linear / nonlinear:.3f} |", flush=True)  # fmt: skip
    print(f"\n{time.perf_counter() - began:.0f} s")


if __name__ == "__main__":
    main()
