"""What one step may cost: CPU and memory, estimated from the inputs before anything is computed.

A footprint's spectra reach 4 / r modes per axis (``footprint``): a legal but tiny radius makes
every part of a step that touches the static correction scale with that reach, and a session
keeps its applied footprints' spectra until the next step. So a step is priced first, from the
footprints' mode counts alone, and refused with its figure when it would cost more than the
engine's budget, like the exact evaluator's memory budget. The budget covers the frame the
step's state will give too (a later ``read`` synthesises it), so no state a step leaves behind
costs more than the budget to read.

Work is counted in units of about a nanosecond of one core of the reference machine (a 2-core
virtual machine, numpy with OpenBLAS; benchmarks/live_cost.py measures the ratio of measured to
estimated time): each term is an operation count times its measured cost per element.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from membrane_models.live.errors import LiveError
from membrane_models.live.synthesis import DENSE_TABLE_ELEMENTS

__all__ = [
    "DEFAULT_MAX_HELD_BYTES",
    "DEFAULT_MAX_STEP_WORK",
    "FootprintSize",
    "StepBudget",
    "StepCost",
    "StepTooCostly",
    "step_cost",
    "table_step_cost",
    "tool_step_cost",
]

# About 5 ms of one core: a step's worst legal cost, bounded so that one session cannot hold
# the serving thread for long (a 200 Hz client waits behind at most one such step).
DEFAULT_MAX_STEP_WORK = 5_000_000
# The applied footprints' spectra a session's state holds (float64 entries, 8 bytes each).
DEFAULT_MAX_HELD_BYTES = 512 * 1024

# Measured costs per element, in work units (ns on the reference machine).
_FOOTPRINT = 8000.0  # a footprint's fixed cost per pass (checks, objects, small products)
_PAIR = 3000.0  # a probe pair's fixed cost (its cross-compliance's bookkeeping)
_SPECTRUM = 16.0  # exp and sin of one Gaussian spectrum entry
_EDGE = 85.0  # one Faddeeva evaluation (an edge-cut footprint's closed-form term)
_PRODUCT = 0.2  # one mode product of a combined box (a matrix product over footprints)
_CROSS = 0.5  # one mode product of a cross-compliance (a matrix-vector product)
_BOX = 1.5  # one entry of a combined box (allocation and the 1 / w^2 weights)
_SYNTHESIS = 0.15  # one mode per lattice point of an axis, synthesising the frame
_FOLD = 4.0  # one coefficient folded onto the modes a lattice resolves
_PIVOT = 2.0  # a tool's contact solves, per cubed point count (a few dense solves)


class StepTooCostly(LiveError):
    """A step whose inputs would cost more than the engine's budget (CPU or held memory)."""


@dataclass(frozen=True)
class FootprintSize:
    """What a footprint costs to build and to use: spectrum entries per axis, and how many of
    them need the edge term (0, 1 or 2 edges per axis)."""

    counts: tuple[int, ...]
    edges: tuple[int, ...]

    @property
    def box(self) -> int:
        """Mode products of one pass over its static-correction box."""
        return math.prod(self.counts)

    @property
    def entries(self) -> int:
        return sum(self.counts)


@dataclass(frozen=True)
class StepCost:
    """A step's estimated work (units: about 1 ns) and the spectra bytes its state holds."""

    work: float
    held_bytes: int


@dataclass(frozen=True)
class StepBudget:
    """The most one step may cost (``max_work`` units, ``max_held_bytes`` of spectra)."""

    max_work: float = DEFAULT_MAX_STEP_WORK
    max_held_bytes: int = DEFAULT_MAX_HELD_BYTES

    def check(self, cost: StepCost) -> None:
        """Raise ``StepTooCostly`` with the figures when ``cost`` is over budget."""
        if cost.work > self.max_work:
            raise StepTooCostly(
                f"this step would cost about {cost.work / 1e6:.3g} ms of work, over the "
                f"{self.max_work / 1e6:.3g} ms a step may take (describe's live.max_step_work): "
                "use fewer or wider footprints"
            )
        if cost.held_bytes > self.max_held_bytes:
            raise StepTooCostly(
                f"this step's footprints hold {cost.held_bytes} bytes of spectra, over the "
                f"{self.max_held_bytes} a session may hold (describe's live.max_held_bytes): "
                "use fewer or wider footprints"
            )


def step_cost(
    loads: Sequence[FootprintSize],
    probes: Sequence[FootprintSize],
    lattice: tuple[int, ...],
    corrected: bool,
) -> StepCost:
    """The estimated cost of a step with these footprints (``probes``: those inside the domain).

    Terms: building every spectrum (and its edge terms); with probes, the loads' combined box
    and each probe's products with it and with every other probe; and the frame of the new
    state (every footprint's box combined, weighted and synthesised), counted whether or not
    this step asks for it. ``corrected``: whether the static correction is on (off, the
    footprints are cut to the stepped box and only their building counts).
    """
    prints = [*loads, *probes]
    work = sum(_FOOTPRINT + _SPECTRUM * p.entries + _EDGE * _edge_entries(p) for p in prints)
    held = 8 * sum(p.entries for p in prints)
    pairs = len(probes) * (len(probes) + 1) // 2
    work += _PAIR * pairs
    if corrected and prints:
        if probes:
            work += _combined(loads)
            work += _CROSS * (sum(p.box for p in probes) + pairs * max(p.box for p in probes))
        work += _combined(prints) + _synthesis(prints, lattice)
    return StepCost(work, held)


def tool_step_cost(
    loads: Sequence[FootprintSize],
    points: Sequence[FootprintSize],
    lattice: tuple[int, ...],
    corrected: bool,
) -> StepCost:
    """The estimated cost of a step with rigid tools whose lattice points push with the
    footprints ``points``: every spectrum and the frame as ``step_cost`` prices them, the free
    frame at the points, and their compliance as the sine basis computes it (over the
    distinct lattice lines and footprint centres: about 1.5 P of them for P points in a disk,
    each a product with the M x M weights, then P^2 sums of M), with the pivots' solves."""
    base = step_cost([*loads, *points], [], lattice, corrected)
    if not points:
        return base
    count = len(points)
    box = max(p.box for p in points)
    side = max(max(p.counts) for p in points)
    work = _CROSS * (1.5 * count * box + count * count * side)
    work += _combined(loads) + _PIVOT * count**3
    return StepCost(base.work + work, base.held_bytes)


def _largest_counts(prints: Sequence[FootprintSize]) -> list[int]:
    """Per axis, the longest spectrum among ``prints``: the combined box's extent."""
    return [max(p.counts[a] for p in prints) for a in range(len(prints[0].counts))]


def _combined(prints: Sequence[FootprintSize]) -> float:
    if not prints:
        return 0.0
    largest = math.prod(_largest_counts(prints))
    return _PRODUCT * len(prints) * largest + _BOX * largest


def _synthesis(prints: Sequence[FootprintSize], lattice: tuple[int, ...]) -> float:
    """The frame's sine products: a dense table per axis, or a fold onto the lattice's modes
    past ``synthesis``'s table size (then a pass over the box and one small product)."""
    counts = _largest_counts(prints)
    box = math.prod(counts)
    if lattice[0] * counts[0] > DENSE_TABLE_ELEMENTS:
        return _FOLD * box + _SYNTHESIS * lattice[0] * (box // counts[0]) * (lattice[0] - 2)
    return _SYNTHESIS * lattice[0] * box


def _edge_entries(footprint: FootprintSize) -> int:
    return sum(n * e for n, e in zip(footprint.counts, footprint.edges, strict=True))


def table_step_cost(loads: int, probes: int, modes: int, points: int) -> StepCost:
    """The estimated cost of a step of a tabulated basis (``tabulated_basis``): every
    footprint's modal force (a table lookup over the modes), the probes' products with one
    another, and the frame (the mode table times q). The footprints hold one float per mode."""
    prints = loads + probes
    pairs = probes * (probes + 1) // 2
    work = _FOOTPRINT * prints + _PAIR * pairs + _CROSS * modes * (prints + pairs)
    work += _SYNTHESIS * points * modes
    return StepCost(work, 8 * modes * prints)
