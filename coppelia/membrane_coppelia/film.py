"""A film in CoppeliaSim: at every step the served frame at the simulation's time.

Each step: ``t = sim.getSimulationTime()``, ``client.query(t)``, move every sphere,
``sim.step()``. The simulator's clock drives the queries, so the film plays at whatever pace
CoppeliaSim steps. The run ends at the scene's end or at ``duration``; past the scene's end its
policy decides (``hold``/``clamp`` keep answering; under ``error`` the run ends there, cleanly).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from membrane_client.errors import ServerError
from membrane_client.frame import SceneInfo
from membrane_client.protocol import ErrorCode
from membrane_coppelia.interrupt import raise_if_interrupted
from membrane_coppelia.lattice import SphereLattice
from membrane_coppelia.options import RunOptions
from membrane_coppelia.results import COMPLETED, MAX_STEPS, OUT_OF_DOMAIN, RunResult, StepTimings

__all__ = ["OnFilmStep", "drive_lattice", "run_film"]

OnFilmStep = Callable[[int, float], None]  # (steps done, simulation time shown)


def run_film(
    lattice: SphereLattice,
    *,
    duration: float | None = None,
    max_steps: int | None = None,
    on_step: OnFilmStep | None = None,
) -> RunResult:
    """Run the simulation in stepping mode, showing the served film at every step.

    Args:
        lattice: the lattice to move (built here if it is not yet).
        duration: simulation time to run to, seconds (default: the scene's end,
            ``start_offset + duration``). Past the scene's end the scene's policy decides:
            under ``error`` the run ends cleanly at the first refused time.
        max_steps: stop after this many steps (default: no limit).
        on_step: called after every step with (steps done, simulation time shown).

    Returns:
        What happened, with per-step timings. The simulation is stopped on return.
    """
    if lattice.parent is None:
        lattice.build()
    info = lattice.scene_info()
    end_t = info.start_offset + info.duration if duration is None else duration
    if not end_t >= 0:
        raise ValueError(f"duration must be >= 0 seconds, got {duration}")
    if max_steps is not None and max_steps < 0:
        raise ValueError(f"max_steps must be >= 0, got {max_steps}")
    try:
        sim_dt = lattice.start()
        return _loop(lattice, info, end_t, max_steps, sim_dt, on_step)
    finally:
        if not lattice.dead:
            lattice.stop()


def _loop(
    lattice: SphereLattice,
    info: SceneInfo,
    end_t: float,
    max_steps: int | None,
    sim_dt: float,
    on_step: OnFilmStep | None,
) -> RunResult:
    sim, client = lattice.sim, lattice.client
    timings = StepTimings()
    steps, first_t, last_t = 0, float("nan"), float("nan")
    positions: np.ndarray | None = None
    reason, message = COMPLETED, ""
    slack = 1e-6 * sim_dt  # float noise of the simulator's clock, not a real overshoot
    while True:
        raise_if_interrupted()  # a signal whose exception a finalizer swallowed
        if max_steps is not None and steps >= max_steps:
            reason = MAX_STEPS
            break
        start = time.perf_counter()
        with lattice.calling("reading the simulation time"):
            t = float(sim.getSimulationTime())
        if t > end_t + slack:
            break
        t = min(t, end_t)
        clock = time.perf_counter()
        if t < info.start_offset and info.policy == "error":
            positions = info.rest_positions()  # before the response starts: at rest
        else:
            try:
                positions = client.query(t).positions()
            except ServerError as exc:
                if exc.code != ErrorCode.OUT_OF_DOMAIN:
                    raise
                reason, message = OUT_OF_DOMAIN, f"stopped at t = {t:g} s: {exc.message}"
                break
        queried = time.perf_counter()
        with lattice.calling("moving the spheres"):
            lattice.move(positions)
        moved = time.perf_counter()
        lattice.step()
        stepped = time.perf_counter()
        timings.add(start, clock, queried, moved, stepped)
        first_t = t if steps == 0 else first_t
        last_t = t
        steps += 1
        if on_step is not None:
            on_step(steps, t)
    if not message:
        message = f"{steps} steps, t = {first_t:g} .. {last_t:g} s ({reason})"
    return RunResult(
        scene=info.name,
        spheres=len(lattice.handles),
        steps=steps,
        first_t=first_t,
        last_t=last_t,
        path=lattice.path,
        reason=reason,
        message=message,
        sim_dt=sim_dt,
        timings=timings,
        last_positions=positions,
    )


def drive_lattice(
    options: RunOptions | None = None, *, on_step: OnFilmStep | None = None
) -> RunResult:
    """Connect to a membrane server and to CoppeliaSim, build the lattice, run the film, clean
    up.

    Args:
        options: where both sides are and how to run (default: :class:`RunOptions`' defaults).
        on_step: as in :func:`run_film`.

    Raises:
        SimulatorTimeout: CoppeliaSim did not answer within ``options.sim_timeout``.
        SimulatorError: CoppeliaSim refused a call.
        membrane_client.Timeout / ServerError: the membrane server did not answer, or refused.
        Interrupted: SIGINT or SIGTERM (under ``interrupt_on``); the simulation was stopped.
    """
    options = options or RunOptions()
    link = options.connect_simulator()
    try:
        with options.client() as client, options.lattice(link, client) as lattice:
            try:
                lattice.build()
                return run_film(
                    lattice,
                    duration=options.duration,
                    max_steps=options.max_steps,
                    on_step=on_step,
                )
            finally:
                link.broken = lattice.dead
    finally:
        link.close()
