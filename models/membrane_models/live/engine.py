"""The exact modal engine: the string's and the membrane's response to live loads and probes.

The response to any load history is a sum over the sine modes; each is a damped oscillator
q'' + 2 zeta w q' + w^2 q = p, p the modal force. This engine is the stepping core
(``stepper.ModalStepper``: the exact 2 x 2 transition per mode, contact, the frame) over the
sine basis (``sine_basis.SineBasis``): it keeps the modes its lattice and its step resolve
(``modes``), adds the static response of the modes it does not step (``static_correction``)
and synthesises frames from the sine tables (``synthesis``).

Scaling: with u = sum q_k phi_k and int phi_k^2 = 2^-d, the modal force of a pressure F g is
p_k = F s_k with s_k = 2^d <g, phi_k> (``footprint``), the footprint-weighted displacement is
z = <g, u> = 2^-d s . q, and the energy of the stepped modes is 2^-d / 2 sum (v^2 + w^2 q^2)
(density 1, problem units).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from membrane_models.live.cost import FootprintSize, StepBudget
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.live.footprint import Footprint
from membrane_models.live.interface import Hold, Load, Probe
from membrane_models.live.modes import choose_modes
from membrane_models.live.sine_basis import DEFAULT_MAX_REACH, SineBasis
from membrane_models.live.static_correction import ResidualFlexibility
from membrane_models.live.stepper import ModalState, ModalStepper, positive
from membrane_models.live.synthesis import LatticeSynthesis
from membrane_models.problems import Problem

__all__ = ["DEFAULT_MAX_REACH", "MAX_LATTICE_POINTS", "ModalEngine", "ModalState"]

MAX_LATTICE_POINTS = 2**22


class ModalEngine(ModalStepper[Footprint]):
    """The exact modal live engine for the string (d = 1) and the membrane (d = 2).

    Args:
        problem: the scene's problem; its wave speed ``c`` and dimension are used.
        lattice: points per axis of the frames (an int: the same on every axis), >= 3 each,
            on the uniform grid linspace(0, 1, n) per axis.
        dt: the step (problem time units), > 0.
        damping: modal damping ratio zeta >= 0 (0: the study's equation), or one per mode of
            the mode box.
        hold: "zoh" (loads constant over a step) or "foh" (linear from the last step's).
        modes: modes per axis to step (default: those the lattice resolves, n - 2).
        step_limit: keep modes with w dt <= step_limit (default pi); None keeps all.
        static_correction: add the static response of the modes not stepped.
        max_reach: most modes per axis the static correction sums (default
            ``DEFAULT_MAX_REACH``); the smallest radius it carries is 4 / max_reach.
        budget: the most one step may cost (``cost.StepBudget``; default 5 ms of work and
            512 KiB of held spectra); a step over it is refused with its figure.

    Raises:
        InvalidEngineSettings: a setting out of range.
    """

    basis: SineBasis

    def __init__(
        self,
        problem: Problem,
        lattice: int | Sequence[int],
        dt: float,
        *,
        damping: float | ArrayLike = 0.0,
        hold: Hold = "zoh",
        modes: int | Sequence[int] | None = None,
        step_limit: float | None = math.pi,
        static_correction: bool = True,
        max_reach: int | None = None,
        budget: StepBudget | None = None,
    ) -> None:
        dims = problem.spatial_dims
        if dims not in (1, 2):
            raise InvalidEngineSettings(f"{problem.name}: only strings and membranes are live")
        self.problem = problem
        points = _lattice(lattice, dims)
        step = positive(dt, "dt")
        limit = None if step_limit is None else positive(step_limit, "step_limit")
        counts = None if modes is None else _counts(modes, dims, "modes")
        chosen = choose_modes(float(problem.c), points, step, counts, limit)
        reach = DEFAULT_MAX_REACH[dims] if max_reach is None else max_reach
        reach = max(_counts(reach, 1, "max_reach")[0], *chosen.box, 1)
        basis = SineBasis(float(problem.c), chosen, points, reach, static_correction)
        super().__init__(basis, step, damping=damping, hold=hold, budget=budget)

    @property
    def max_reach(self) -> int:
        return self.basis.max_reach

    @property
    def min_radius(self) -> float:
        """The smallest footprint radius the static correction carries (0: a point, string)."""
        return self.basis.min_radius

    @property
    def residual(self) -> ResidualFlexibility:
        return self.basis.residual

    @property
    def synthesis(self) -> LatticeSynthesis:
        return self.basis.synthesis

    def footprint_size(self, item: Load | Probe, kind: str, index: int) -> FootprintSize:
        """The spectrum entries a footprint needs per axis (``SineBasis.footprint_size``)."""
        return self.basis.footprint_size(item, kind, index)

    def _footprint(self, item: Load | Probe, size: FootprintSize, kind: str) -> Footprint:
        return self.basis.footprint(item, size, kind)

    def subject(self) -> dict[str, object]:
        """The scene's problem, by name."""
        return {"problem": self.problem.name}


def _lattice(lattice: int | Sequence[int], dims: int) -> tuple[int, ...]:
    counts = _counts(lattice, dims, "lattice")
    if any(n < 3 for n in counts):
        raise InvalidEngineSettings(f"the lattice needs >= 3 points per axis, got {counts}")
    if math.prod(counts) > MAX_LATTICE_POINTS:
        raise InvalidEngineSettings(f"the lattice has more than {MAX_LATTICE_POINTS} points")
    return counts


def _counts(value: int | Sequence[int], dims: int, what: str) -> tuple[int, ...]:
    values = [value] * dims if isinstance(value, int) else list(value)
    if len(values) != dims or not all(
        isinstance(n, int | np.integer) and not isinstance(n, bool) and n >= 1 for n in values
    ):
        raise InvalidEngineSettings(f"{what} must be {dims} positive integer(s)")
    return tuple(int(n) for n in values)
