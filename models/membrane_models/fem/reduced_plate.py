"""A von Karman plate reduced to a few coordinates, its internal forces cubic in them.

The deflection is w = V q on r basis vectors V: the plate's lowest modes, optionally with the
static responses to point forces at chosen points (contact-adapted vectors), Ritz-diagonalised
so that V' M V = I and V' K V = diag(omega^2). The in-plane field is condensed statically, not
by modal derivatives: for every pair (j, k) the in-plane displacement U_jk that the quadratic
strain of v_j and v_k drives,

    K_uu U_jk = -b_jk,   b_jk(v) = int C(e_jk) : sym grad v,

e_jk = (g_j (x) g_k + g_k (x) g_j) / 4 and g_j = grad v_j, so that for w in span V the
membrane strain is exactly eps(q) = sum_jk q_j q_k E_jk, E_jk = sym grad U_jk + e_jk, and the
stretching energy the quartic

    V_s(q) = 1/2 sum G_jklm q_j q_k q_l q_m,   G_jklm = int C(E_jk) : E_lm,

precomputed once (the in-plane field has no inertia in the full model either:
``nonlinear_transient``). Its force 2 sum G_iklm q_k q_l q_m is the cubic polynomial of Barbic
and James (2005), here computed exactly rather than fitted.

What V does not carry is kept as the linear static residual at the lattice points,
R = S K^-1 S' - S V diag(omega^-2) V' S' (m/N, S sampling w there), which the live engine adds
under a tool's point forces as the linear modal engine adds its static correction.

Units: SI; q in sqrt(kg) m (mass-normalised), omega in rad/s, G in N / (kg^2 m^2).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import SuperLU, splu

from membrane_models.fem.assembly import System
from membrane_models.fem.condensation import Condensation
from membrane_models.fem.errors import InvalidModel, InvalidSolve
from membrane_models.fem.modal import Modes
from membrane_models.fem.modal import modes as lowest_modes
from membrane_models.fem.models import Plate
from membrane_models.fem.sampling import sampler
from membrane_models.fem.static import point_load
from membrane_models.fem.tables import boundary_segments, inside_mesh, lattice_points

__all__ = ["ReducedPlate", "quartic_from_pairs", "reduce_plate"]

FloatArray = NDArray[np.float64]
# The quartic's pairs are built this many at a time: each holds its strain at every quadrature
# point (4 x 8 bytes x elements x points per element).
_PAIR_CHUNK = 64


@dataclass(frozen=True, eq=False)
class ReducedPlate:
    """The reduced von Karman plate (module docstring).

    Attributes:
        omega: the Ritz vectors' angular frequencies (r,), rad/s, ascending.
        quartic: G (r, r, r, r), symmetric under j <-> k, l <-> m and (jk) <-> (lm).
        shapes: V at the lattice points (points, r), m per unit q (0 where w cannot move).
        residual: R at the lattice points (points, points), m/N.
        movable: the lattice points the plate can move at (inside, not on a held edge).
        lattice, lower, upper: the lattice (points per axis) over the box (m).
        modes: how many of the r vectors are the plate's modes (the rest: static vectors).
        boundary: the mesh's boundary segments (segments, 2, 2), m: what ``contains`` tests.
        vectors: V on every DOF of the system it was reduced from (DOFs, r), m per unit q:
            what a contact-adapted vector is made orthogonal to (``adapted_basis``).
    """

    omega: FloatArray
    quartic: FloatArray
    shapes: FloatArray
    residual: FloatArray
    movable: NDArray[np.bool_]
    lattice: tuple[int, int]
    lower: tuple[float, float]
    upper: tuple[float, float]
    modes: int
    boundary: FloatArray
    vectors: FloatArray

    @property
    def size(self) -> int:
        """r, the reduced coordinates."""
        return int(self.omega.size)

    @functools.cached_property
    def pairs(self) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
        """The pairs j <= k as index arrays (J, K), and ``index[j, k]`` -> pair (symmetric)."""
        r = self.size
        first, second = np.triu_indices(r)
        index = np.zeros((r, r), dtype=np.intp)
        index[first, second] = index[second, first] = np.arange(first.size)
        return first, second, index

    @functools.cached_property
    def pair_rows(self) -> NDArray[np.intp]:
        """The pairs' (J, K) as the rows of one (2, pairs) array (the compiled step's form)."""
        first, second, _ = self.pairs
        rows = np.ascontiguousarray(np.stack([first, second]))
        rows.setflags(write=False)
        return rows

    @functools.cached_property
    def pairs_matrix(self) -> FloatArray:
        """G on the pairs, weighted so that H(Q)_jk = (pairs_matrix @ Q_pairs)[pair(j, k)] for a
        symmetric Q given on the pairs j <= k (an off-diagonal pair stands for two entries)."""
        first, second, _ = self.pairs
        weights = np.where(first == second, 1.0, 2.0)
        packed = self.quartic[first, second][:, first, second] * weights
        return np.ascontiguousarray(packed)

    @functools.cached_property
    def crossed_matrix(self) -> FloatArray:
        """G as (r^2, r^2), rows (i, j), columns (k, m) for G_ikjm: the tangent's
        sum_km G_ikjm a_k b_m = (crossed @ (a b').ravel()) reshaped."""
        r = self.size
        crossed = np.transpose(self.quartic, (0, 2, 1, 3)).reshape(r * r, r * r)
        return np.ascontiguousarray(crossed)

    def pair_products(self, q: FloatArray) -> FloatArray:
        """q_j q_k on the pairs j <= k."""
        first, second, _ = self.pairs
        return np.asarray(q[first] * q[second])

    def contracted(self, pairs: FloatArray) -> FloatArray:
        """H(Q) (r, r) of a symmetric Q given on the pairs."""
        return np.asarray((self.pairs_matrix @ pairs)[self.pairs[2]])

    @property
    def coordinates(self) -> FloatArray:
        """The lattice points, x-major (points, 2), m."""
        return lattice_points(self.lower, self.upper, self.lattice)

    def stretching_energy(self, q: FloatArray) -> float:
        """V_s(q) (J)."""
        return 0.5 * float(np.sum(self.contracted(self.pair_products(q)) * np.outer(q, q)))

    def stretching_force(self, q: FloatArray) -> FloatArray:
        """dV_s / dq = 2 sum G_iklm q_k q_l q_m (N per unit q)."""
        return np.asarray(2.0 * self.contracted(self.pair_products(q)) @ q)


def reduce_plate(
    system: System,
    count: int,
    lattice: tuple[int, int],
    inplane: Mapping[str, str] | str = "held",
    static_points: Sequence[tuple[float, float]] = (),
) -> ReducedPlate:
    """The reduced plate of ``system`` (an Argyris ``Plate``): its ``count`` lowest modes and
    the static responses to unit point forces at ``static_points`` (m), the in-plane supports
    ``inplane`` (``nonlinear``'s), and the residual on ``lattice``.

    Raises:
        InvalidModel: not an Argyris plate.
        InvalidSolve: a count or a lattice out of range, or static points the modes already
            span (a vector that adds nothing).
    """
    plate = system.model
    if not isinstance(plate, Plate) or system.element != "argyris":
        raise InvalidModel("a reduced von Karman plate needs an Argyris plate (a Plate system)")
    if len(lattice) != 2 or min(lattice) < 3:
        raise InvalidSolve(f"the lattice needs 2 axes of >= 3 points, got {tuple(lattice)}")
    found = lowest_modes(system, count)
    factor = splu(sp.csc_matrix(system.reduced_stiffness))
    omega, vectors = _ritz(system, found, factor, static_points)
    quartic = _quartic(system, vectors, inplane)
    points = system.domain.mesh.p
    lower = (float(points[0].min()), float(points[1].min()))
    upper = (float(points[0].max()), float(points[1].max()))
    xy = lattice_points(lower, upper, lattice)
    inside = inside_mesh(system, xy)
    rows = sampler(system, xy[inside])
    shapes = np.zeros((xy.shape[0], omega.size))
    shapes[inside] = rows @ vectors
    residual = np.zeros((xy.shape[0], xy.shape[0]))
    reduced_rows = np.asarray((rows @ system.transform).toarray())
    flexibility = reduced_rows @ factor.solve(np.ascontiguousarray(reduced_rows.T))
    kept = shapes[inside] / omega
    residual[np.ix_(inside, inside)] = flexibility - kept @ kept.T
    residual = 0.5 * (residual + residual.T)
    movable = np.zeros(xy.shape[0], dtype=bool)
    movable[inside] = np.diag(flexibility) > 1e-12 * float(np.diag(flexibility).max())
    size = (int(lattice[0]), int(lattice[1]))
    segments = boundary_segments(system)
    return ReducedPlate(omega, quartic, shapes, residual, movable, size, lower, upper,
                        found.count, segments, vectors)  # fmt: skip


def _ritz(
    system: System,
    modes: Modes,
    factor: SuperLU,
    static_points: Sequence[tuple[float, float]],
) -> tuple[FloatArray, FloatArray]:
    """The modes and the static vectors, Ritz-diagonalised: (omega, V on every DOF)."""
    if not static_points:
        return modes.omega, modes.shapes
    loads = np.stack([system.reduce(point_load(system, 1.0, p)) for p in static_points], axis=1)
    statics = system.expand(factor.solve(loads))
    candidates = np.concatenate([modes.shapes, statics], axis=1)
    m, k = system.mass, system.stiffness
    mass = candidates.T @ (m @ candidates)
    stiffness = candidates.T @ (k @ candidates)
    # refuse a static response the others nearly span: its Ritz problem would be singular
    scale = np.sqrt(np.diag(mass))
    values = np.linalg.eigvalsh(mass / np.outer(scale, scale))
    if values.min() < 1e-10 * values.max():
        raise InvalidSolve("the static points' responses are (nearly) spanned by the modes")
    eigenvalues, ritz = scipy.linalg.eigh(stiffness, mass)
    vectors = candidates @ ritz
    return np.asarray(np.sqrt(np.clip(eigenvalues, 0.0, None))), np.asarray(vectors)


def _quartic(system: System, vectors: FloatArray, inplane: Mapping[str, str] | str) -> FloatArray:
    """G of the basis ``vectors`` (on every DOF), the in-plane field condensed."""
    condensation = Condensation.of(system, inplane)
    slopes = condensation.slopes(vectors)
    r = vectors.shape[1]
    first, second = np.triu_indices(r)
    components = []  # per pair: E_xx, E_yy, E_xy at every quadrature point, times sqrt(dx)
    for start in range(0, first.size, _PAIR_CHUNK):
        left, right = first[start : start + _PAIR_CHUNK], second[start : start + _PAIR_CHUNK]
        strain = condensation.condensed(condensation.quadratic(slopes[left], slopes[right]))
        components.append(condensation.components(strain))
    x = np.concatenate(components)
    g_pairs = condensation.products(x, x)
    return quartic_from_pairs(0.5 * (g_pairs + g_pairs.T), r)  # (jk) <-> (lm) to the last bit


def quartic_from_pairs(g_pairs: FloatArray, r: int) -> FloatArray:
    """G (r, r, r, r) from its values on the pairs j <= k (rows and columns in
    ``np.triu_indices(r)``'s order), filled by its symmetries."""
    first, second = np.triu_indices(r)
    quartic = np.zeros((r, r, r, r))
    for row, j, k in zip(g_pairs, first, second, strict=True):
        quartic[j, k, first, second] = row
        quartic[j, k, second, first] = row
        quartic[k, j] = quartic[j, k]
    return quartic
