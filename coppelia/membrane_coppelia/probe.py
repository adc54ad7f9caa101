"""The live probe path: a scene object presses the tissue, the spheres show it, the force returns.

On a live scene (``membrane-live``, ``rope-live``) each simulation step:

1. reads the probe object's position (a robot's tool tip, or a dummy the user drags) relative to
   the lattice's parent dummy: as placed, that is the served world frame;
2. turns it into the probe the session takes (:class:`TipMapping`, the inverse of the scene's
   placement): lattice coordinates on the axes across the displacement axis, and the depth of the
   tip below the rest surface, in problem units; a tip at or above the surface sends no probe and
   reads force 0;
3. steps the live session with it and moves the spheres to the returned frame;
4. writes the contact force back (``--force-signal``), for a controller or a haptic bridge;
5. ``sim.step()``.

The session's time and the simulator's advance together: the simulator's time step is set to the
scene's dt before the start (a time step that does not take is an error).
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from membrane_client.errors import MembraneError, UserError
from membrane_client.frame import SceneInfo
from membrane_client.session import Probe, Session
from membrane_coppelia.compat import SimCalls
from membrane_coppelia.interrupt import raise_if_interrupted
from membrane_coppelia.lattice import SphereLattice
from membrane_coppelia.link import ObjectNotFound, SimulatorError
from membrane_coppelia.options import RunOptions
from membrane_coppelia.results import COMPLETED, MAX_STEPS, ProbeRunResult, StepTimings

__all__ = [
    "DEFAULT_PROBE_RADIUS",
    "ForceSignal",
    "OnProbeStep",
    "TipMapping",
    "drive_probe",
    "find_object",
    "run_probe",
]

log = logging.getLogger(__name__)

DEFAULT_PROBE_RADIUS = 0.05  # problem units: the study's load radius, 1 / sqrt(k)
SIGNAL_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")

OnProbeStep = Callable[[int, float, float], None]  # (steps done, session time, contact force)


@dataclass(frozen=True)
class TipMapping:
    """The inverse of a scene's placement, for a probe tip.

    A lattice point at coordinates ``p`` (problem units) rests at ``origin + size * p`` on the
    world axes across ``axis`` and is displaced by ``scale * z`` along ``axis``. A probe presses
    along -axis, so a tip at height ``h`` along ``axis`` is ``(origin[axis] - h) / scale`` deep.
    """

    origin: np.ndarray  # (3,) world position of lattice coordinate 0
    size: float  # world length of one lattice unit
    scale: float  # world length of one unit of displacement
    axis: int  # 0, 1, 2: the displacement axis
    dims: int  # lattice dimensions: 1 (rope) or 2 (membrane)

    @classmethod
    def from_info(cls, info: SceneInfo) -> TipMapping:
        if not (info.size > 0 and info.scale > 0):
            raise UserError(f"scene {info.name}: placement size and scale must be > 0")
        origin = np.asarray(info.origin, dtype=np.float64)
        return cls(origin, info.size, info.scale, info.axis_index, int(info.points.shape[1]))

    @property
    def lateral(self) -> list[int]:
        """The world axes the lattice's coordinates lie on, in x, y, z order (as the placement)."""
        return [i for i in range(3) if i != self.axis][: self.dims]

    def coordinates(self, tip: Sequence[float]) -> tuple[float, ...]:
        """The tip's lattice coordinates (problem units). On a rope, the offset across it is
        ignored: a rope is a line, and a tip beside it presses it all the same."""
        return tuple((float(tip[i]) - float(self.origin[i])) / self.size for i in self.lateral)

    def depth(self, tip: Sequence[float]) -> float:
        """How far the tip is below the rest surface, in problem units (<= 0: above it)."""
        return (float(self.origin[self.axis]) - float(tip[self.axis])) / self.scale

    def probe(self, tip: Sequence[float], radius: float) -> Probe | None:
        """The probe for a tip (None when at or above the rest surface: no contact)."""
        depth = self.depth(tip)
        if not depth > 0.0:
            return None
        return Probe(self.coordinates(tip), depth, radius)


class ForceSignal:
    """Writes the contact force into the simulation each step, with the call the version has:
    ``sim.setFloatProperty(sim.handle_scene, 'signal.NAME', f)`` from 4.8,
    ``sim.setFloatSignal('NAME', f)`` before."""

    def __init__(self, calls: SimCalls, name: str) -> None:
        _check_signal_name(name)
        self.calls, self.name = calls, name

    def write(self, force: float) -> None:
        self.calls.write_float_signal(self.name, force)

    def describe(self) -> str:
        return self.calls.signal_call.replace("NAME", self.name)


def find_object(lattice: SphereLattice, path: str) -> int:
    """The handle of the scene object at ``path`` (``sim.getObject``, e.g. '/UR5/tip')."""
    try:
        with lattice.calling(f"looking up {path!r}"):
            return int(lattice.sim.getObject(path))
    except ObjectNotFound:
        raise
    except SimulatorError as exc:
        if lattice.dead:
            raise
        raise ObjectNotFound(f"no object {path!r} in CoppeliaSim's scene ({exc})") from None


def run_probe(
    lattice: SphereLattice,
    session: Session,
    tip: int,
    *,
    radius: float = DEFAULT_PROBE_RADIUS,
    signal: str | None = None,
    duration: float | None = None,
    max_steps: int | None = None,
    on_step: OnProbeStep | None = None,
) -> ProbeRunResult:
    """Run the simulation in stepping mode, pressing the session's tissue with object ``tip``.

    Args:
        lattice: built on the session's scene (``lattice.build(session.info)``).
        session: an open live session.
        tip: the handle of the object that presses.
        radius: the probe's radius, problem units (> 0).
        signal: write the contact force to this float signal each step.
        duration: session time to run to, s; ``max_steps``: steps to take. With neither, the
            run goes on until interrupted.
        on_step: called after every step with (steps done, session time, contact force).

    Returns:
        What happened. The simulation is stopped on return.
    """
    _check_probe_arguments(radius, signal)
    if duration is not None and not duration >= 0:
        raise UserError(f"duration must be >= 0 seconds, got {duration}")
    if lattice.calls is None or lattice.info is None:
        raise RuntimeError("build() the lattice first")
    writer = ForceSignal(lattice.calls, signal) if signal is not None else None
    if signal is not None:  # after an interrupt too: no controller keeps a stale force
        lattice.on_recover(lambda sim: ForceSignal(SimCalls(sim), signal).write(0.0))
    try:
        sim_dt = lattice.start()
        result = _loop(lattice, session, tip, radius, writer, duration, max_steps, on_step)
        result.sim_dt = sim_dt
        return result
    finally:
        if writer is not None and not lattice.dead:
            _zero_signal(lattice, writer)
        if not lattice.dead:
            lattice.stop()


def _check_probe_arguments(radius: float, signal: str | None) -> None:
    if not (math.isfinite(radius) and radius > 0):
        raise UserError(f"the probe radius must be > 0 (problem units), got {radius}")
    if signal is not None:
        _check_signal_name(signal)


def _check_signal_name(name: str) -> None:
    if SIGNAL_NAME.fullmatch(name) is None:
        raise UserError(f"a signal name is letters, digits and '_' (1-64), got {name!r}")


def _loop(
    lattice: SphereLattice,
    session: Session,
    tip: int,
    radius: float,
    writer: ForceSignal | None,
    duration: float | None,
    max_steps: int | None,
    on_step: OnProbeStep | None,
) -> ProbeRunResult:
    info = lattice.scene_info()
    mapping = TipMapping.from_info(info)
    result = ProbeRunResult(
        scene=info.name,
        spheres=len(lattice.handles),
        steps=0,
        path=lattice.path,
        reason=COMPLETED,
        message="",
        sim_dt=float("nan"),
        timings=StepTimings(),
        signal=writer.describe() if writer is not None else None,
    )
    timings, sim, parent = result.timings, lattice.sim, lattice.parent
    end_k = math.inf if duration is None else round(duration / info.dt)
    while result.steps < end_k:
        raise_if_interrupted()  # a signal whose exception a finalizer swallowed
        if max_steps is not None and result.steps >= max_steps:
            result.reason = MAX_STEPS
            break
        start = time.perf_counter()
        with lattice.calling("reading the probe's position"):
            x, y, z = (float(v) for v in sim.getObjectPosition(tip, parent))
        read = time.perf_counter()
        probe = mapping.probe((x, y, z), radius)
        frame = session.step(probes=[probe] if probe is not None else [])
        force = float(frame.probes[0].force) if probe is not None else 0.0
        stepped = time.perf_counter()
        positions = frame.positions()
        with lattice.calling("moving the spheres"):
            lattice.move(positions)
            if writer is not None:
                writer.write(force)
        moved = time.perf_counter()
        lattice.step()
        done = time.perf_counter()
        timings.add(start, read, stepped, moved, done)
        result.tips.append((x, y, z))
        result.depths.append(mapping.depth((x, y, z)))
        result.forces.append(force)
        result.last_positions = positions
        result.steps += 1
        if on_step is not None:
            on_step(result.steps, frame.t, force)
    contact = sum(1 for f in result.forces if f > 0.0)
    peak = max(result.forces, default=0.0)
    result.message = (
        f"{result.steps} steps ({result.reason}), in contact for {contact}, "
        f"peak force {peak:.4g} (problem units)"
    )
    return result


def _zero_signal(lattice: SphereLattice, writer: ForceSignal) -> None:
    # A controller must not keep reading the last contact force after the run.
    try:
        with lattice.calling("clearing the force signal"):
            writer.write(0.0)
    except SimulatorError as exc:
        log.warning("could not set the force signal to 0: %s", exc)


def _close_quietly(session: Session) -> None:
    # After an interrupt the client's socket may be stuck mid-request; the server expires the
    # session by itself (its idle timeout), so failing to close it is no error.
    try:
        session.close()
    except MembraneError as exc:
        log.info("could not close the live session: %s", exc)


def drive_probe(
    probe_path: str,
    options: RunOptions | None = None,
    *,
    radius: float = DEFAULT_PROBE_RADIUS,
    force_signal: str | None = None,
    on_step: OnProbeStep | None = None,
) -> ProbeRunResult:
    """Connect to both sides, open a live session, build the lattice, press it with the object
    at ``probe_path``, clean up.

    Args:
        probe_path: the pressing object's path in the scene (``sim.getObject``, e.g. '/UR5/tip').
        options: where both sides are and how to run (default: :class:`RunOptions`' defaults;
            with neither ``duration`` nor ``max_steps`` the run goes on until interrupted).
        radius, force_signal (``signal``), on_step: as in :func:`run_probe`.

    Raises:
        ObjectNotFound: no object at ``probe_path``.
        membrane_client.ServerError: e.g. ``not_live`` for a scene that is not live.
        Interrupted: SIGINT or SIGTERM (under ``interrupt_on``); the simulation was stopped.
    """
    _check_probe_arguments(radius, force_signal)  # before connecting to anything
    options = options or RunOptions()
    link = options.connect_simulator()
    try:
        with options.client() as client:
            session = client.session(options.scene)
            try:
                with options.lattice(link, client) as lattice:
                    try:
                        tip = find_object(lattice, probe_path)
                        lattice.build(session.info)
                        return run_probe(
                            lattice,
                            session,
                            tip,
                            radius=radius,
                            signal=force_signal,
                            duration=options.duration,
                            max_steps=options.max_steps,
                            on_step=on_step,
                        )
                    finally:
                        link.broken = lattice.dead
            finally:
                _close_quietly(session)
    finally:
        link.close()
