"""A dynamic press and release of the skin patch: the reduced von Karman plate against the full
one in time (docs/NONLINEAR.md, "In time").

    python benchmarks/nonlinear_dynamics.py [--size 0.005] [--modes 8,12,20]

The study's patch (50 mm, clamped, edges held in their plane) on a mesh of ``--size`` elements,
no damping, pressed at its centre by a point force ramped to 1.5 N over 10 ms (a smooth step),
held to 25 ms, released over 5 ms and left to ring to 60 ms, at dt = 1 ms (the scenes'):

- the full plate: Newmark's average acceleration with Newton at every step, every DOF
  (``fem.nonlinear_transient``);
- the reduced plate at each mode count: the discrete-gradient step (``fem.reduced_dynamics``),
  the force as a modal load and the residual's static share under it.

Relative L2 over the 21 x 21 lattice and all 61 times, and of the centre's history alone; the
peak centre deflection against the linear plate's static one at 1.5 N.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from membrane_models import fem
from membrane_models.fem.nonlinear_transient import step_nonlinear
from membrane_models.fem.reduced_dynamics import StepCoefficients, step_reduced
from membrane_models.fem.reduced_plate import reduce_plate
from membrane_models.fem.sampling import sampler
from membrane_models.fem.tables import inside_mesh

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
CENTRE, PEAK, DT, STEPS = (0.025, 0.025), -1.5, 1e-3, 60


def force(t: float) -> float:
    """The press's force (N, along +z) at time t (s)."""

    def smooth(x: float) -> float:
        x = min(max(x, 0.0), 1.0)
        return x * x * (3.0 - 2.0 * x)

    return PEAK * (smooth(t / 0.010) - smooth((t - 0.025) / 0.005))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=0.005)
    parser.add_argument("--modes", default="8,12,20")
    args = parser.parse_args()
    system = fem.assemble(fem.rectangle(0.05, 0.05, args.size), SKIN, "clamped")
    unit = fem.point_load(system, 1.0, CENTRE)
    began = time.perf_counter()
    run = step_nonlinear(system, lambda t: force(t) * unit, DT, STEPS)
    spent = time.perf_counter() - began
    some = reduce_plate(system, 8, (21, 21), "held")
    xy = some.coordinates
    inside = inside_mesh(system, xy)
    rows = sampler(system, xy[inside])
    full = np.zeros((STEPS + 1, xy.shape[0]))
    full[:, inside] = (rows @ run.w.T).T
    centre = int(np.argmin(((xy - CENTRE) ** 2).sum(axis=1)))
    linear = fem.sample(system, fem.solve(system, PEAK * unit), [CENTRE])[0]
    print(f"mesh {system.dofs} DOFs; full plate: {STEPS} steps in {spent:.0f} s, "
          f"{run.iterations} Newton iterations; peak centre {full[:, centre].min() * 1e3:.4f} mm "
          f"(the linear plate's static at 1.5 N: {linear * 1e3:.4f} mm)")  # fmt: skip
    print("\n| modes | rel. L2, lattice x time | rel. L2, centre | peak centre (mm) |")
    print("| --- | --- | --- | --- |")
    none = np.zeros(0, dtype=np.intp)
    for count in (int(c) for c in args.modes.split(",")):
        plate = reduce_plate(system, count, (21, 21), "held")
        coefficients = StepCoefficients.of(plate, DT, 0.0)
        q, v, matrix = np.zeros(plate.size), np.zeros(plate.size), None
        frames = [np.zeros(xy.shape[0])]
        for n in range(1, STEPS + 1):
            # the step's mean force held over it (Newmark's trapezoid of the end values)
            f = 0.5 * (force((n - 1) * DT) + force(n * DT))
            load = f * plate.shapes[centre]
            solved = step_reduced(plate, coefficients, q, v, none, np.zeros(0), load=load,
                                  matrix=matrix)  # fmt: skip
            q, v, matrix = solved.q, solved.v, solved.matrix
            frames.append(plate.shapes @ q + plate.residual[:, centre] * force(n * DT))
        ours = np.array(frames)
        whole = np.linalg.norm(ours - full) / np.linalg.norm(full)
        middle = np.linalg.norm(ours[:, centre] - full[:, centre]) / np.linalg.norm(full[:, centre])
        print(f"| {count} | {whole:.3e} | {middle:.3e} | {ours[:, centre].min() * 1e3:.4f} |")


if __name__ == "__main__":
    main()
