"""Contact-adapted basis vectors added to a reduced plate without rebuilding it.

A sphere pressed into the skin patch dimples it locally; the lowest modes carry the dimple's
bending only through the linear residual, which does not stretch. The static response to a
unit point force at the tool's centre (Barbic and James's contact-adapted vector) carries it.
Given the reduced plate's modes V (V' M V = I, V' K V = Omega^2) and the static responses
S = K^-1 F to unit point forces F at k points, the added vectors are

    T = S - V (V' M S),   then Ritz-diagonalised among themselves (T' M T = I, T' K T diagonal),

mass-orthogonal to the modes and so also stiffness-orthogonal to them (V' K T = Omega^2 V' M T
= 0, K V = M V Omega^2): [V T] is a Ritz basis whose first r coordinates mean what they meant.
So only what T brings is new (``condensation``): the in-plane solves of the pairs (j, a) with a
new vector a, r k + k (k + 1) / 2 of them, and their rows of the quartic, G_(ja)(lm) =
int C(E_ja) : e_lm against every pair's quadratic strain, no solve for the old pairs. The
residual at the lattice loses T's share, R - S_T diag(omega_T^-2) S_T' (S_T: T at the lattice).

A state moves between two such bases of the same modes by the mass-orthogonal projection
(``carried``): q_modes unchanged, the added coordinates a_B = T_B' M T_A a_A. Displacement and
energy are unchanged when a_A = 0 (the tool has not pressed yet), and otherwise the
displacement changes by the part of T_A a_A outside span T_B, the kinetic energy can only drop.

Units: SI, as ``reduced_plate``'s (points in m, unit forces in N).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import SuperLU, splu

from membrane_models.fem.assembly import System
from membrane_models.fem.condensation import Condensation
from membrane_models.fem.errors import InvalidSolve
from membrane_models.fem.reduced_plate import ReducedPlate, quartic_from_pairs
from membrane_models.fem.sampling import sampler
from membrane_models.fem.static import point_load
from membrane_models.fem.tables import inside_mesh

__all__ = ["Adaptation", "AdaptedPlate", "carried"]

FloatArray = NDArray[np.float64]
_PAIR_CHUNK = 64  # new pairs whose strain is held at once (4 x 8 B x E x Q each)
# An added vector whose part outside the span of the others is below this fraction of its
# mass norm adds nothing: refused rather than a near-singular Ritz problem.
_SPANNED = 1e-5


@dataclass(frozen=True, eq=False)
class AdaptedPlate:
    """A reduced plate with contact-adapted vectors: the base's r modes, then k static vectors.

    Attributes:
        plate: the reduced plate of the r + k vectors.
        points: where the unit forces of the k vectors are applied (m).
        weighted: M T (DOFs, k), what ``carried`` projects onto.
    """

    plate: ReducedPlate = field(repr=False)
    points: tuple[tuple[float, float], ...]
    weighted: FloatArray = field(repr=False)

    @property
    def added(self) -> FloatArray:
        """T on every DOF (DOFs, k), m per unit coordinate."""
        return self.plate.vectors[:, self.plate.modes :]


def carried(
    values: FloatArray, source: AdaptedPlate | ReducedPlate, target: AdaptedPlate
) -> FloatArray:
    """Coordinates (q, v or an acceleration) on ``source``'s basis projected onto ``target``'s
    (the same modes): the modes' unchanged, the added ones T_B' M T_A a (module docstring)."""
    r = target.plate.modes
    projected = np.zeros(target.plate.size)
    projected[:r] = values[:r]
    if isinstance(source, AdaptedPlate) and source.plate.size > r:
        projected[r:] = target.added.T @ (source.weighted @ values[r:])
    return projected


@dataclass(frozen=True, eq=False)
class Adaptation:
    """What adding vectors to ``base`` needs beyond the plate (module docstring): its system's
    factored stiffness, the condensation and the modes' slopes, the lattice's sampling rows.
    Building it costs about what one added vector does (the factorisations)."""

    base: ReducedPlate
    system: System
    factor: SuperLU
    condensation: Condensation
    slopes: FloatArray
    inside: NDArray[np.bool_]
    rows: sp.csr_matrix

    @classmethod
    def of(cls, system: System, base: ReducedPlate, inplane: Mapping[str, str] | str) -> Adaptation:
        """The adaptation of ``base``, reduced from ``system`` with ``inplane`` supports."""
        if base.size != base.modes or base.vectors.shape != (system.dofs, base.size):
            raise InvalidSolve("a plate is adapted from its modes alone, on its own system")
        factor = splu(sp.csc_matrix(system.reduced_stiffness))
        condensation = Condensation.of(system, inplane)
        slopes = condensation.slopes(base.vectors)
        inside = inside_mesh(system, base.coordinates)
        rows = sp.csr_matrix(sampler(system, base.coordinates[inside]))
        return cls(base, system, factor, condensation, slopes, inside, rows)

    def adapted(self, points: Sequence[tuple[float, float]]) -> AdaptedPlate:
        """The base plate with the static responses to unit point forces at ``points`` (m).

        Raises:
            InvalidSolve: no point, or a response the modes and the others (nearly) span.
            OutsideDomain: a point off the mesh.
        """
        if not points:
            raise InvalidSolve("a contact-adapted basis needs at least one point")
        system, base = self.system, self.base
        loads = np.stack([system.reduce(point_load(system, 1.0, p)) for p in points], axis=1)
        added = system.expand(self.factor.solve(loads))
        omega_added, added = self._orthogonal(added)
        vectors = np.concatenate([base.vectors, added], axis=1)
        omega = np.concatenate([base.omega, omega_added])
        quartic = self._quartic(added)
        sampled = np.zeros((base.shapes.shape[0], added.shape[1]))
        sampled[self.inside] = self.rows @ added
        shapes = np.concatenate([base.shapes, sampled], axis=1)
        kept = sampled / omega_added
        residual = base.residual - kept @ kept.T
        plate = replace(base, omega=omega, quartic=quartic, shapes=shapes,
                        residual=0.5 * (residual + residual.T), vectors=vectors)  # fmt: skip
        fixed = tuple((float(x), float(y)) for x, y in points)
        return AdaptedPlate(plate, fixed, np.asarray(system.mass @ added))

    def _orthogonal(self, statics: FloatArray) -> tuple[FloatArray, FloatArray]:
        """T from S (module docstring): (omega_T, T on every DOF)."""
        m, modes = self.system.mass, self.base.vectors
        weighted = m @ statics
        scale = np.sqrt(np.einsum("ik,ik->k", statics, weighted))
        outside = statics - modes @ (modes.T @ weighted)
        mass = outside.T @ (m @ outside)
        values = np.linalg.eigvalsh(mass / np.outer(scale, scale))
        if values.min() < _SPANNED**2:
            raise InvalidSolve("the points' static responses are (nearly) spanned by the basis")
        stiffness = outside.T @ (self.system.stiffness @ outside)
        eigenvalues, ritz = scipy.linalg.eigh(stiffness, mass)
        return np.sqrt(np.clip(eigenvalues, 0.0, None)), np.asarray(outside @ ritz)

    def _quartic(self, added: FloatArray) -> FloatArray:
        """G of [V T]: the base's block kept, the rows of every pair with a new vector added."""
        c, r, k = self.condensation, self.base.size, added.shape[1]
        n = r + k
        slopes = np.concatenate([self.slopes, c.slopes(added)])
        first, second = np.triu_indices(n)
        new = np.flatnonzero(second >= r)
        old = np.flatnonzero(second < r)
        rows = np.empty((new.size, first.size))
        for start in range(0, new.size, _PAIR_CHUNK):
            chunk = new[start : start + _PAIR_CHUNK]
            e = c.quadratic(slopes[first[chunk]], slopes[second[chunk]])
            products = c.against_slopes(c.condensed(e), slopes)  # (chunk, n, n)
            rows[start : start + chunk.size] = products[:, first, second]
        block = rows[:, new]
        rows[:, new] = 0.5 * (block + block.T)
        g_pairs = np.empty((first.size, first.size))
        g_old = self.base.quartic[first[old], second[old]]  # (old pairs, r, r)
        g_pairs[np.ix_(old, old)] = g_old[:, first[old], second[old]]
        g_pairs[new] = rows
        g_pairs[:, new] = rows.T
        return quartic_from_pairs(g_pairs, n)
