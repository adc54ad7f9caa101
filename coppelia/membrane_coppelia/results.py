"""What a run reports: how it ended, what it showed, and how long each part of a step took.

A film run (:func:`~membrane_coppelia.film.run_film`) returns a :class:`RunResult`, a probe run
(:func:`~membrane_coppelia.probe.run_probe`) a :class:`ProbeRunResult`; both carry the same
:class:`StepTimings`, so that the two paths' costs compare part by part.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "COMPLETED",
    "MAX_STEPS",
    "OUT_OF_DOMAIN",
    "ProbeRunResult",
    "RunResult",
    "StepTimings",
]

# Why a run ended.
COMPLETED = "completed"
OUT_OF_DOMAIN = "out_of_domain"
MAX_STEPS = "max_steps"


@dataclass
class StepTimings:
    """Wall-clock seconds spent in each part of every step.

    ``read``: reading the simulator (the simulation time, or a probe's position); ``query``: the
    membrane server's answer (a film's ``query``, a live session's ``step``); ``move``: moving
    every sphere (one call when batched, one per sphere otherwise); ``step``: ``sim.step()``
    with its handshake; ``total``: the whole step.
    """

    read: list[float] = field(default_factory=list)
    query: list[float] = field(default_factory=list)
    move: list[float] = field(default_factory=list)
    step: list[float] = field(default_factory=list)
    total: list[float] = field(default_factory=list)

    def add(self, start: float, read: float, answered: float, moved: float, stepped: float) -> None:
        """Record one step from its ``time.perf_counter()`` marks: begun, simulator read,
        server answered, spheres moved, simulator stepped."""
        self.read.append(read - start)
        self.query.append(answered - read)
        self.move.append(moved - answered)
        self.step.append(stepped - moved)
        self.total.append(stepped - start)

    def percentiles(self) -> dict[str, dict[str, float]]:
        """``{part: {"p50": s, "p99": s}}`` for the parts measured at least once."""
        parts = {
            "read": self.read,
            "query": self.query,
            "move": self.move,
            "step": self.step,
            "total": self.total,
        }
        return {
            name: {
                "p50": float(np.percentile(values, 50)),
                "p99": float(np.percentile(values, 99)),
            }
            for name, values in parts.items()
            if values
        }

    def summary(self) -> str:
        """One line: p50 / p99 in milliseconds of every part."""
        return "  ".join(
            f"{name} {p['p50'] * 1e3:.3f}/{p['p99'] * 1e3:.3f} ms"
            for name, p in self.percentiles().items()
        )


@dataclass
class RunResult:
    """What a film run did.

    Attributes:
        scene: the scene's name.
        spheres: how many spheres the lattice has.
        steps: simulation steps taken.
        first_t, last_t: simulation times of the first and last frame shown (NaN if none).
        path: how spheres moved, ``"batched"`` or ``"per-sphere"``.
        reason: why the run ended: ``"completed"`` (end time reached), ``"max_steps"``, or
            ``"out_of_domain"`` (the server refused a time under the scene's ``error`` policy).
        message: one line for people about how the run ended.
        sim_dt: the simulator's time step during the run.
        timings: per-step wall-clock times.
        last_positions: (n, 3) positions sent at the last step (world coordinates as served).
    """

    scene: str
    spheres: int
    steps: int
    first_t: float
    last_t: float
    path: str
    reason: str
    message: str
    sim_dt: float
    timings: StepTimings
    last_positions: np.ndarray | None


@dataclass
class ProbeRunResult:
    """What a probe run did.

    Attributes:
        scene, spheres, path, sim_dt, timings: as in :class:`RunResult` (``timings.read`` is
            reading the tip, ``timings.query`` the session's step).
        steps: simulation steps taken.
        reason: ``"completed"`` (``duration`` reached) or ``"max_steps"``.
        message: one line for people.
        depths, forces: per step, the tip's depth (problem units, <= 0 above the surface) and
            the contact force read back (0 out of contact).
        tips: (steps, 3) tip positions read, relative to the lattice's parent dummy.
        last_positions: (n, 3) sphere positions sent at the last step.
        signal: the call that wrote the force, if any.
    """

    scene: str
    spheres: int
    steps: int
    path: str
    reason: str
    message: str
    sim_dt: float
    timings: StepTimings
    depths: list[float] = field(default_factory=list)
    forces: list[float] = field(default_factory=list)
    tips: list[tuple[float, float, float]] = field(default_factory=list)
    last_positions: np.ndarray | None = None
    signal: str | None = None
