"""The von Karman plate at large deflection against Hencky's membrane (docs/NONLINEAR.md).

    python benchmarks/hencky.py [--quick]

A clamped circular plate under uniform pressure q, its edge held in its plane (nu = 0.3,
a = 50 mm, h = 0.5 mm: a / h = 100, so rotations stay moderate at w0 / h of about 18). As the
load grows, bending matters less and the centre deflection tends to Hencky's membrane,
w0 = C a (q a / (E h))^(1/3) with C = 0.653 at nu = 0.3, i.e.
w0 / h = C (q a^4 / (E h^4))^(1/3). Printed:

1. the approach: w0 over Hencky's w0 for q a^4 / (E h^4) from 1e2 to 2e4 on one graded mesh;
2. at 2e4, the ratio over refinements of the graded mesh (every edge size halved; the rim band,
   0.03 a wide, meshed at a tenth of the interior's edge), and on ungraded meshes, where the
   clamped edge's boundary layer (a few times sqrt(D / N), about 0.02-0.03 a here) is left to
   the interior's triangles.

Each solve starts from the flat plate (``fem.solve_nonlinear``'s adaptive load increments).
"""

from __future__ import annotations

import argparse
import time

from membrane_models import fem
from membrane_models.fem.nonlinear import solve_nonlinear

A, H, NU = 0.05, 0.0005, 0.3
HENCKY_C = 0.653  # Hencky (1915), the constant for nu = 0.3
RIM_WIDTH = 0.03 * A
PLATE = fem.Plate(youngs_modulus=1.0e6, poisson=NU, thickness=H, density=1000.0)


def graded(size: float) -> fem.Domain:
    return fem.ellipse(A, A, size, rim_size=size / 10, rim_width=RIM_WIDTH)


def centre_ratio(domain: fem.Domain, load_number: float) -> tuple[float, float, str]:
    """(FEM w0 / h, FEM w0 over Hencky's, the solve's figures) at q a^4 / (E h^4)."""
    system = fem.assemble(domain, PLATE, "clamped")
    q = load_number * PLATE.youngs_modulus * H**4 / A**4
    began = time.perf_counter()
    state = solve_nonlinear(system, fem.pressure_load(system, q), "held")
    w0 = abs(fem.sample(system, state.w, [(0.0, 0.0)])[0]) / H
    hencky = HENCKY_C * load_number ** (1 / 3)
    figures = (
        f"{domain.triangles} triangles, {system.dofs} DOFs, {state.increments} increments, "
        f"{state.iterations} iterations, {time.perf_counter() - began:.0f} s"
    )
    return w0, w0 / hencky, figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the two coarsest meshes only")
    args = parser.parse_args()
    sizes = (A / 2, A / 4) if args.quick else (A / 2, A / 4, A / 8)

    print("## The approach to Hencky's membrane (graded mesh, interior edge a / 4)\n")
    print("| q a^4 / (E h^4) | FEM w0/h | Hencky w0/h | ratio | solve |")
    print("| --- | --- | --- | --- | --- |")
    domain = graded(A / 4)
    for load_number in (1e2, 1e3, 1e4, 2e4):
        w0, ratio, figures = centre_ratio(domain, load_number)
        hencky = HENCKY_C * load_number ** (1 / 3)
        print(f"| {load_number:.0e} | {w0:.4f} | {hencky:.4f} | {ratio:.5f} | {figures} |",
              flush=True)  # fmt: skip

    print("\n## At q a^4 / (E h^4) = 2e4: refinement, graded and not\n")
    print("| mesh | interior edge / a | rim edge / a | ratio | solve |")
    print("| --- | --- | --- | --- | --- |")
    for size in sizes:
        _, ratio, figures = centre_ratio(graded(size), 2e4)
        print(f"| graded | {size / A:.4g} | {size / 10 / A:.4g} | {ratio:.5f} | {figures} |",
              flush=True)  # fmt: skip
    for size in sizes[:2]:
        _, ratio, figures = centre_ratio(fem.ellipse(A, A, size / 4), 2e4)
        print(f"| ungraded | {size / 4 / A:.4g} | {size / 4 / A:.4g} | {ratio:.5f} | {figures} |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
