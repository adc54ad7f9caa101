"""The study's skin patch as a live FEM model: cold and cached build times, and the tables' error.

50 mm square, clamped, E 1.5 MPa, nu 0.45, rho 1109 kg/m^3, h 3 mm; Argyris triangles of
2.5 mm; 100 modes, the static correction, a 20 x 20 lattice, point forces and Gaussian
footprints of radius 2.5 mm.

1. Cold (an empty cache directory): mesh, assembly, the 100 lowest modes, the live tables,
   and writing them; then the same from the cache (mesh, key, read, verify).
2. The centre compliance under a point load against the plate's accurate value
   0.005612 a^2 / D.
3. The tables read between their nodes, at 50 random centres 3 mm or more inside the edges
   (point forces and footprints),
   against the same quantities computed directly on the mesh: the modal forces (relative to
   their norm) and the compliance under the footprint, the stepped modes' part and the static
   correction's (relative to the whole, f' K^-1 f).

    python benchmarks/fem_skin_patch.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from membrane_models import fem
from membrane_models.fem.cache import TableCache, cached_tables
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tables import footprint_loads, live_tables
from membrane_models.live import Load
from membrane_models.live.tabulated_basis import TabulatedBasis

SIDE, ELEMENT, RADIUS = 0.05, 0.0025, 0.0025
SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
LATTICE = (20, 20)
OPTIONS = {"count": 100, "lattice": LATTICE, "radii": [0.0, RADIUS]}


def main() -> None:
    with tempfile.TemporaryDirectory() as directory:
        cache = TableCache(Path(directory))
        started = time.perf_counter()
        domain = fem.rectangle(SIDE, SIDE, ELEMENT)
        tables, hit = cached_tables(domain, SKIN, "clamped", cache=cache, **OPTIONS)  # type: ignore[arg-type]
        cold = time.perf_counter() - started
        assert not hit
        started = time.perf_counter()
        domain = fem.rectangle(SIDE, SIDE, ELEMENT)
        _, hit = cached_tables(domain, SKIN, "clamped", cache=cache, **OPTIONS)  # type: ignore[arg-type]
        warm = time.perf_counter() - started
        assert hit
    print(f"cold: {cold:.2f} s (mesh, assembly, 100 modes, tables: {tables.nbytes / 1e6:.1f} MB)")
    print(f"from the cache: {warm:.3f} s")
    system = fem.assemble(domain, SKIN, "clamped")
    modes = fem.modes(system, 100)
    centre = (SIDE / 2, SIDE / 2)
    w = float(fem.sample(system, fem.solve(system, fem.point_load(system, 1.0, centre)), centre))
    accurate = 0.005612 * SIDE**2 / SKIN.rigidity
    print(f"centre compliance, point load: {w * 1e3:.5f} mm/N, accurate {accurate * 1e3:.5f} "
          f"mm/N ({w / accurate - 1:+.2e}); {system.free} free DOFs")  # fmt: skip
    # The same modes on both sides (a degenerate pair's vectors are any basis of its plane).
    basis = fem_basis(live_tables(system, modes, LATTICE, [RADIUS, 0.0]))
    rng = np.random.default_rng(1)
    centres = rng.uniform(0.003, SIDE - 0.003, size=(50, 2))
    print("| quantity (50 centres) | footprint | worst | median |")
    print("| --- | --- | --- | --- |")
    for radius, kind in ((RADIUS, "Gaussian, r = 2.5 mm"), (0.0, "point force")):
        for name, values in _errors(system, modes, basis, radius, centres).items():
            print(f"| {name} | {kind} | {max(values):.2e} | {float(np.median(values)):.2e} |")


def _errors(
    system: fem.System, modes: fem.Modes, basis: TabulatedBasis, radius: float, centres: np.ndarray
) -> dict[str, list[float]]:
    """The tables' errors at ``centres`` against the mesh, for footprints of ``radius``."""
    loads = footprint_loads(system, radius, centres)
    exact_forces = modes.shapes.T @ loads
    errors: dict[str, list[float]] = {
        "modal forces, relative to their norm": [],
        "stepped compliance, relative to the compliance": [],
        "static correction, relative to the compliance": [],
        "the static correction's share of the compliance": [],
    }
    rows = list(errors.values())
    for k, at in enumerate(map(tuple, centres)):
        footprint = basis._footprint(Load(at, 1.0, radius), "load", 0)
        compliance = float(loads[:, k] @ fem.solve(system, loads[:, k]))
        exact_stepped = float(np.sum(exact_forces[:, k] ** 2 / modes.omega**2))
        stepped = float(np.sum(footprint.modal_force**2 / modes.omega**2))
        difference = np.linalg.norm(footprint.modal_force - exact_forces[:, k])
        rows[0].append(float(difference / np.linalg.norm(exact_forces[:, k])))
        rows[1].append(abs(stepped - exact_stepped) / compliance)
        rows[2].append(abs(basis.own(footprint) - (compliance - exact_stepped)) / compliance)
        rows[3].append((compliance - exact_stepped) / compliance)
    return errors


if __name__ == "__main__":
    main()
