"""What the stepping core needs of a modal basis: its modes, footprints, static correction, frames.

The live core (``stepper.ModalStepper``) steps damped modal oscillators under loads and
probes; everything that depends on which modes they are lives behind this interface. The sine
modes of the unit string and square (``sine_basis.SineBasis``, closed-form spectra) are one
basis; modes tabulated on the lattice (``tabulated_basis.TabulatedBasis``: FEM modes, or the sine
modes fed as tables in the test that ties the two) are another.

Conventions every basis keeps, so that the core is the same for all of them:

- the modal amplitudes q live on the basis's mode box (``modes.box``), ``modes.kept`` marking
  the ones stepped (the others stay 0);
- a footprint's modal force per unit total force is the array s on that box
  (``modal_force``): a force F on it adds F s to the modes' equations q'' + ... = p;
- the footprint-weighted displacement of the stepped modes is ``scale * s . q`` (``scale`` is
  2^-d for the sine modes, whose norm is 2^-d; 1 for mass-normalised modes), and their energy
  ``scale / 2 * sum(v^2 + w^2 q^2)``;
- the static correction (the modes not stepped) is the basis's own: ``own`` and ``cross`` give
  its compliance under footprints, ``loads_residual`` the loads' displacement under a probe,
  and ``frame`` adds its field to the stepped modes' on the lattice.

A footprint is the basis's own object (the core only passes it back); a probe outside the
basis's domain has none (``footprints`` gives None) and touches nothing.

Rigid tools (``tools``) constrain lattice points, each pushed by a footprint of the basis's
``tool_force_radius``: ``point_frame`` gives the frame at a few lattice points and
``point_compliance`` their one-step compliance to those footprints, both exactly as ``frame``
would show them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.cost import StepBudget
from membrane_models.live.interface import Load, Probe
from membrane_models.live.modes import ModeSet

__all__ = ["FootprintT", "ModalBasis"]

FloatArray = NDArray[np.float64]
FootprintT = TypeVar("FootprintT")


class ModalBasis(Protocol[FootprintT]):
    """A modal basis the stepping core can step (module docstring for the conventions)."""

    @property
    def spatial_dims(self) -> int:
        """Coordinates of a load's or probe's centre."""

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        """Points per axis of the frames (x-major)."""

    @property
    def modes(self) -> ModeSet:
        """The mode box, its angular frequencies and the stepped ones."""

    @property
    def scale(self) -> float:
        """The weight of ``s . q`` in a footprint's displacement (and of the energy)."""

    @property
    def static_correction(self) -> bool:
        """Whether the modes not stepped keep their static compliance."""

    @property
    def memory_bytes(self) -> int:
        """Bytes the basis holds now (tables, weights)."""

    @property
    def engine_bytes(self) -> int:
        """The most the basis and any caches it shares hold, whatever sessions send."""

    @property
    def lattice_coordinates(self) -> FloatArray:
        """Every lattice point's coordinates, (points, dims), x-major (read-only)."""

    @property
    def movable(self) -> NDArray[np.bool_]:
        """Which lattice points the tissue can move at (not clamped, inside the domain)."""

    @property
    def tool_force_radius(self) -> float | None:
        """The footprint radius a tool's point pushes with (None: this basis carries none)."""

    def contains(self, at: tuple[float, ...]) -> bool:
        """Whether a centre lies in the domain (a load outside it is refused)."""

    def footprints(
        self,
        loads: Sequence[Load],
        probes: Sequence[Probe],
        budget: StepBudget,
        *,
        tool_points: bool = False,
    ) -> tuple[list[FootprintT], list[FootprintT | None]]:
        """The loads' and probes' footprints (None: a probe outside the domain), after
        pricing the step against ``budget`` (``tool_points``: the probes are a tool's lattice
        points, each pushing with its footprint; their spectra may be cached).

        Raises:
            StepTooCostly: the step would cost more than ``budget``.
            InvalidLoad, InvalidProbe: a footprint the basis cannot carry.
        """

    def modal_force(self, footprint: FootprintT) -> FloatArray:
        """s on the mode box: the modal force per unit force on ``footprint``."""

    def modal_factors(self, footprint: FootprintT) -> tuple[FloatArray, FloatArray] | None:
        """``modal_force`` as an outer product x (x) y of per-axis factors on the mode box
        (a string's y is [1]), which a step builds in its own pass; None where it is not one."""

    def own(self, footprint: FootprintT) -> float:
        """The static correction's compliance under ``footprint`` (0 without it)."""

    def cross(self, a: FootprintT, b: FootprintT) -> float:
        """The static correction's displacement under ``b`` per unit force on ``a``."""

    def loads_residual(
        self, prints: Sequence[FootprintT], forces: Sequence[float]
    ) -> Callable[[FootprintT], float]:
        """The loads' static-correction displacement under a probe's footprint."""

    def frame(self, q: FloatArray, applied: Sequence[tuple[FootprintT, float]]) -> FloatArray:
        """Displacements on the lattice (x-major, flattened): the modes ``q`` plus the static
        correction's field of the forces ``applied``."""

    def point_frame(
        self,
        points: NDArray[np.intp],
        q: FloatArray,
        applied: Sequence[tuple[FootprintT, float]],
    ) -> FloatArray:
        """``frame(q, applied)`` at the lattice points ``points`` only."""

    def point_compliance(
        self, points: NDArray[np.intp], prints: Sequence[FootprintT], gain: FloatArray
    ) -> FloatArray:
        """(points, prints): the frame's value at each point per unit force held on each
        footprint over a step whose stepped modes respond by ``gain`` (on the mode box) to a
        unit modal force, with the static correction of the others."""

    def project(self, shape: ArrayLike, what: str) -> tuple[FloatArray, float]:
        """Least-squares modal amplitudes of a shape on the lattice (0 off the stepped modes)
        and the relative residual.

        Raises:
            InvalidShape: wrong size, not finite, or out of range.
        """

    def describe(self) -> dict[str, object]:
        """What the basis says of itself in the engine's description (plain data)."""
