"""A reduced plate's contact-adapted vectors kept where the tools are, built off the step.

The vector for a tool (``adapted_basis``: the static response to a unit point force) is put
at the tool's centre rounded to a grid of ``spacing`` (m), so that the places a basis can have
are finite and a basis built once serves every later visit and every session (least recently
used first out, ``capacity`` of them). A state's basis fits its tools while every tool's centre
is within ``spacing`` of one of the basis's points and there are as many points as tools; with
no tool any basis fits (nothing to adapt to). When it does not fit, the basis of the tools'
rounded centres is stepped on if it is built, else its build is started in a worker process
(one at a time: the newest wish is built when the last build ends) and the step goes on with
the state's basis meanwhile. Stepping never waits for a build (a build costs about 0.3 s on
the skin patch, its first one a few seconds more: the worker's start, the system and the
condensation), unless the follower is made to ``wait``: then the step that needs a place waits
for its build, and which basis a step is taken on depends on the tools alone, not on how long
the builds took (reproducible runs, offline simulators; never a haptic loop). A process, not
a thread: a build holds the interpreter's lock between numpy's calls, and the steps' tail grew
longer beside a thread than beside a process (docs/NONLINEAR.md,
``benchmarks/nonlinear_tradeoff.py --builds-beside``).

Units: SI (m).
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import TypeVar

from membrane_models.fem.adapted_basis import Adaptation, AdaptedPlate
from membrane_models.fem.errors import FemError

__all__ = ["WORKER_NICENESS", "BasisFollower", "Places"]

logger = logging.getLogger(__name__)
Places = tuple[tuple[float, float], ...]
WORKER_NICENESS = 5  # the worker's, above the steps' process (a build yields to a step)
_T = TypeVar("_T")


class BasisFollower:
    """The adapted bases of one reduced plate (module docstring): which one a state's tools
    should be stepped on, and their builds off the step's thread.

    ``adaptation`` makes the ``Adaptation`` (seconds: the system and its factorisations); it is
    called once, in the worker process, by the first build, so it must pickle (a module-level
    function, or a ``functools.partial`` of one). ``wait``: ``follow`` waits for the build of
    the place it is asked for (module docstring)."""

    def __init__(
        self,
        adaptation: Callable[[], Adaptation],
        spacing: float,
        capacity: int = 8,
        *,
        wait: bool = False,
    ) -> None:
        if not (math.isfinite(spacing) and spacing > 0.0) or capacity < 1:
            raise ValueError("the spacing must be positive and the capacity at least 1")
        self.spacing = spacing
        self.capacity = capacity
        self.waits = wait
        self._make = adaptation
        self._built: OrderedDict[Places, AdaptedPlate] = OrderedDict()
        self._refused: set[Places] = set()
        self._pending: tuple[Places, Future[AdaptedPlate | None]] | None = None
        self._lock = threading.Lock()
        self._worker: ProcessPoolExecutor | None = None
        self._warming: Future[None] | None = None
        self._broken = False
        self._last_fit: tuple[AdaptedPlate, list[tuple[float, ...]]] | None = None

    def places(self, centres: Sequence[tuple[float, ...]]) -> Places:
        """The tools' centres rounded to the grid, sorted, without repeats."""
        step = self.spacing
        rounded = {(round(c[0] / step) * step, round(c[1] / step) * step) for c in centres}
        return tuple(sorted(rounded))

    def fits(self, basis: AdaptedPlate | None, centres: Sequence[tuple[float, ...]]) -> bool:
        """Whether ``basis`` (None: the modes alone) suits tools at ``centres`` (m)."""
        if not centres:
            return True
        last = self._last_fit  # a held tool asks the same every step (one tuple: thread-safe)
        if last is not None and basis is last[0] and list(centres) == last[1]:
            return True
        if basis is None or len(basis.points) != len(self.places(centres)):
            return False
        reach = self.spacing * (1.0 + 1e-9)
        if all(min(math.dist(c[:2], p) for p in basis.points) <= reach for c in centres):
            self._last_fit = (basis, list(centres))
            return True
        return False

    def follow(
        self, basis: AdaptedPlate | None, centres: Sequence[tuple[float, ...]]
    ) -> AdaptedPlate | None:
        """The basis to step on for tools at ``centres``: ``basis`` while it fits or while the
        one that would is not built yet (its build then started; with ``wait``, waited for),
        else that one. A place the worker could not build leaves ``basis``."""
        if self.fits(basis, centres):
            return basis
        wanted = self.places(centres)
        while True:
            with self._lock:
                self._collect()
                built = self._built.get(wanted)
                if built is not None:
                    self._built.move_to_end(wanted)
                    return built
                if wanted not in self._refused and self._pending is None and not self._broken:
                    self._start(wanted)
                pending = self._pending
            if not self.waits or pending is None:  # not waiting, refused, or no worker
                return basis
            pending[1].exception()  # another place's build first, if one was under way

    def prepare(self) -> None:
        """Start the worker and make what builds need (seconds), so that the first place asked
        for is built in a fraction of a second; nothing if it is under way or done."""
        with self._lock:
            if self._worker is None and not self._broken:
                self._open()
                self._warming = self._submit(_prepare, self._make)

    def wait(self) -> None:
        """Until the worker's preparation and the build under way (if any) have ended: for
        tests and static benchmarks, never for a step."""
        with self._lock:
            pending, warming = self._pending, self._warming
        if warming is not None:
            warming.exception()
        if pending is not None:
            pending[1].exception()
        with self._lock:
            self._collect()

    def close(self) -> None:
        """Stop the worker (a build under way is finished first)."""
        if self._worker is not None:
            self._worker.shutdown(wait=True)
            self._worker = None

    def _open(self) -> None:
        # spawned, not forked: a fork of a process whose threads hold locks (zmq's, BLAS's)
        # may hang; a spawned worker imports the main module as a module, so a script that
        # steps the engine needs the ``if __name__ == "__main__"`` guard
        context = multiprocessing.get_context("spawn")
        self._worker = ProcessPoolExecutor(1, context, _open_worker)

    def _start(self, wanted: Places) -> None:
        if self._worker is None:
            self._open()
            self._warming = self._submit(_prepare, self._make)
        future = self._submit(_build, wanted)
        if future is not None:
            self._pending = (wanted, future)

    def _submit(self, job: Callable[..., _T], *args: object) -> Future[_T] | None:
        """``job`` on the worker, or None once the worker has died (the modes alone then)."""
        assert self._worker is not None
        if self._broken:
            return None
        try:
            return self._worker.submit(job, *args)
        except Exception:  # a dead worker, or one that could not start (what it was given)
            logger.exception("the adapted bases' worker is gone: the modes alone from now on")
            self._broken = True
            return None

    def _collect(self) -> None:
        """Take the finished build in (the lock held)."""
        if self._pending is None or not self._pending[1].done():
            return
        wanted, future = self._pending
        self._pending = None
        try:
            built = future.result()
        except Exception:  # the build's own fault: logged, that place left to the modes
            logger.exception("building the adapted basis at %s failed", wanted)
            built = None
        if built is None:
            self._refused.add(wanted)
            return
        self._built[wanted] = built
        while len(self._built) > self.capacity:
            self._built.popitem(last=False)


# The worker process's own: what its preparation made.
_made: list[Adaptation] = []


def _open_worker() -> None:
    """The worker's start: below the steps in priority, its BLAS on one thread (a threaded
    BLAS here would take the core the steps run on). Nothing large is passed here: a spawned
    process's start arguments are written while its parent waits, the plate is sent as a job."""
    os.nice(WORKER_NICENESS)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # the server's extra brings it; without it the BLAS keeps its threads
        return
    threadpool_limits(limits=1, user_api="blas")


def _prepare(make: Callable[[], Adaptation]) -> None:
    """The worker's ``Adaptation``, made once, before the first place is built (the worker's
    jobs run in the order they were given)."""
    if not _made:
        _made.append(make())


def _build(wanted: Places) -> AdaptedPlate | None:
    """The adapted basis at ``wanted``, in the worker; None where there is none.

    Raises:
        RuntimeError: the worker's preparation failed (the place is then given up).
    """
    if not _made:
        raise RuntimeError("the worker has no adaptation: its preparation failed")
    try:
        return _made[0].adapted(wanted)
    except FemError as error:  # a point off the mesh, or a response the modes span
        logger.info("no adapted basis at %s: %s", wanted, error)
        return None
