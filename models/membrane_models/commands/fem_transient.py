"""`membrane fem transient`: the live engine under a load suddenly applied, or ramped.

The engine is the one `membrane serve` steps for a FEM tissue: ``ModalStepper`` over
``fem_basis`` of the model's live tables (``fem.cache.cached_tables``: modes, footprints, the
static correction of the modes not stepped), read from the cache when it holds them. The load
is the live engine's Gaussian footprint of ``--tool-radius`` (``tables``); the deflection
under it is its footprint-weighted displacement z = scale s . q + F r, r the static
correction's compliance of the footprint on itself (what a probe there would read). The static
deflection is the same footprint's, solved directly: F f' K^-1 f (``fem.solve``).

A sudden load is held from the first step (zero-order hold); a ramp F min(1, t / ramp) is
stepped with a first-order hold, exact for a load linear over each step.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_cli.arguments import UsageError
from membrane_models import fem
from membrane_models.commands.fem_setup import (
    Tissue,
    describe,
    load_point,
    millimetres,
    positive,
    tissue,
)
from membrane_models.fem.cache import TableCache, cached_tables
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tables import LiveTables, footprint_loads
from membrane_models.live import Hold, Load
from membrane_models.live.stepper import ModalStepper
from membrane_models.physical.units import format_quantity, parse_quantity

__all__ = ["LATTICE", "MAX_STEPS", "History", "Timing", "run_transient"]

FloatArray = NDArray[np.float64]
LATTICE = (21, 21)  # the tables' frame lattice (frames are not drawn here: any small one)
MAX_STEPS = 1_000_000
_QUIET = 1.0  # s: say what is happening on stderr once a stage takes longer than this
_PREFIX = "membrane fem transient"
_PER_PERIOD = 20  # steps per first-mode period below which the peak is said to be undersampled


@dataclass(frozen=True)
class Timing:
    """The stepping: step (s), steps, ramp (s, 0: sudden), damping ratio."""

    dt: float
    steps: int
    ramp: float
    damping: float

    def force(self, peak: float, t: float) -> float:
        """The load at time ``t`` (N)."""
        return peak if self.ramp == 0.0 else peak * min(1.0, t / self.ramp)


@dataclass(frozen=True)
class History:
    """The deflection under the load at rest and at the end of each step: t (s), w (m)."""

    t: FloatArray
    w: FloatArray

    @property
    def peak(self) -> tuple[float, float]:
        """The largest |w|, signed, and when (s)."""
        index = int(np.argmax(np.abs(self.w)))
        return float(self.w[index]), float(self.t[index])


def run_transient(args: argparse.Namespace) -> int:
    """The handler of ``membrane fem transient``."""
    item = tissue(args)
    at = load_point(args, item.domain)
    force = parse_quantity(args.load or "1N", "force", name="--load")
    if force == 0.0:
        raise UsageError("--load 0: a zero load deflects nothing")
    radius = positive(args.tool_radius, "length", "--tool-radius")
    timing = _timing(args)
    tables, hit, cache_dir = _tables(item, args, radius)
    history = _step(tables, timing, force, at, radius)
    _warn_coarse(timing, float(tables.omega[0]))
    system = fem.assemble(item.domain, item.model, item.supports)
    static = force * _footprint_compliance(system, radius, at)
    peak, when = history.peak
    print("\n".join(_report(item, system, args, timing, force, at, radius, hit, cache_dir)))
    print(f"peak deflection under the load: {peak * 1e3:.4g} mm at {when * 1e3:.4g} ms")
    print(f"static deflection (fem.solve, the same footprint): {static * 1e3:.4g} mm")
    print(f"ratio peak / static: {peak / static:.4g}{_ratio_note(timing)}")
    if args.plot is not None:
        from membrane_models.commands.fem_plots import plot_history  # matplotlib

        title = f"{item.label}: {format_quantity(force, 'force')} at {millimetres(at)}"
        plot_history(args.plot, history.t, history.w, static, title)
        print(f"plot: {args.plot}")
    return 0


def _timing(args: argparse.Namespace) -> Timing:
    duration = positive(args.duration, "time", "--duration")
    dt = positive(args.dt, "time", "--dt")
    ramp = positive(args.ramp, "time", "--ramp", zero=True)
    if dt > duration:
        raise UsageError(f"--dt {args.dt} is longer than --duration {args.duration}")
    steps = math.ceil(duration / dt - 1e-9)
    if steps > MAX_STEPS:
        raise UsageError(
            f"--duration {args.duration} / --dt {args.dt} is {steps} steps: at most {MAX_STEPS}"
        )
    return Timing(dt, steps, ramp, args.damping)


def _tables(item: Tissue, args: argparse.Namespace, radius: float) -> tuple[LiveTables, bool, str]:
    """The live tables (from the cache when it holds them), whether they came from it, where."""
    cache = TableCache(args.cache_dir)
    note = (
        f"{_PREFIX}: building the live tables ({args.count} modes); they are cached for next time"
    )
    timer = threading.Timer(_QUIET, lambda: print(note, file=sys.stderr, flush=True))
    timer.daemon = True
    timer.start()
    try:
        tables, hit = cached_tables(
            item.domain,
            item.model,
            item.supports,
            count=args.count,
            lattice=LATTICE,
            radii=[radius],
            cache=cache,
        )
    finally:
        timer.cancel()
    return tables, hit, str(cache.directory)


def _step(
    tables: LiveTables, timing: Timing, force: float, at: FloatArray, radius: float
) -> History:
    """Step the live engine under the load; w under it after each step."""
    hold: Hold = "foh" if timing.ramp > 0 else "zoh"
    engine = ModalStepper(fem_basis(tables), timing.dt, damping=timing.damping, hold=hold)
    centre = (float(at[0]), float(at[1]))
    footprint = engine.basis.footprints([Load(centre, 1.0, radius)], [], engine.budget)[0][0]
    weights, own = engine.basis.scale * footprint.modal_force, engine.basis.own(footprint)
    state = engine.start().state
    t, w = np.zeros(timing.steps + 1), np.zeros(timing.steps + 1)
    progress = _Progress(timing.steps)
    for index in range(1, timing.steps + 1):
        t[index] = index * timing.dt
        load = timing.force(force, t[index])
        state = engine.step(state, [Load(centre, load, radius)], [], frame=False).state
        w[index] = float(weights @ state.q) + load * own
        progress.tick(index)
    return History(t, w)


def _footprint_compliance(system: fem.System, radius: float, at: FloatArray) -> float:
    """f' K^-1 f (m/N) of the unit Gaussian footprint at ``at``."""
    load = footprint_loads(system, radius, np.asarray(at, dtype=np.float64)[None, :])[:, 0]
    return float(load @ fem.solve(system, load))


def _report(
    item: Tissue,
    system: fem.System,
    args: argparse.Namespace,
    timing: Timing,
    force: float,
    at: FloatArray,
    radius: float,
    hit: bool,
    cache_dir: str,
) -> list[str]:
    source = "read from the cache" if hit else "built and stored in the cache"
    ramp = format_quantity(timing.ramp, "time")
    applied = "applied suddenly" if timing.ramp == 0 else f"ramped up over {ramp}"
    return [
        *describe(item, system),
        f"live tables: {args.count} modes, {format_quantity(radius, 'length')} footprint, "
        f"{source} ({cache_dir})",
        f"load: {format_quantity(force, 'force')} Gaussian footprint r = "
        f"{format_quantity(radius, 'length')} at {millimetres(at)}, {applied}",
        f"stepping: dt {format_quantity(timing.dt, 'time')}, {timing.steps} steps "
        f"({format_quantity(timing.steps * timing.dt, 'time')}), damping {timing.damping:g}",
    ]


def _warn_coarse(timing: Timing, omega: float) -> None:
    """One line when the steps sample the first mode's period fewer than 20 times."""
    period = 2 * math.pi / omega
    if timing.dt > period / _PER_PERIOD:
        print(
            f"{_PREFIX}: warning: --dt {format_quantity(timing.dt, 'time')} samples the first "
            f"mode's period ({format_quantity(period, 'time')}) fewer than {_PER_PERIOD} times: "
            "the steps are exact, but the peak may fall between them",
            file=sys.stderr,
        )


def _ratio_note(timing: Timing) -> str:
    if timing.ramp == 0 and timing.damping == 0:
        return " (a suddenly applied load on an undamped oscillator: 2)"
    return ""


class _Progress:
    """Steps done, on stderr, once stepping has taken more than a second (then every second)."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.started = time.perf_counter()
        self.next = self.started + _QUIET

    def tick(self, done: int) -> None:
        now = time.perf_counter()
        if now < self.next:
            return
        self.next = now + 1.0
        print(
            f"{_PREFIX}: stepping, {done} of {self.total} steps ({done / self.total:.0%})",
            file=sys.stderr,
            flush=True,
        )
