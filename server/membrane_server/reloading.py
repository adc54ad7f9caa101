"""Reloading scenes without a pause: the new ones are built beside the old, then swapped in.

Building a scene can take seconds (an exact scene with dt 1e-4 precomputes 10,000 frames). The
serving thread must keep answering meanwhile, so a ``SceneBuilder`` builds in a worker thread
and the loop swaps the result in between two requests. The builder's heavy work is numpy and
onnxruntime, which release the GIL; its Python work yields the GIL every switch interval, which
is lowered from 5 ms to 0.5 ms during a build so that a request waits for it at most that long.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from membrane_server.served import ServedScene

__all__ = ["SceneBuilder", "describe_changes"]

logger = logging.getLogger(__name__)

# The GIL switch interval during a build (seconds): how long a request may wait for the GIL.
_BUILD_SWITCH_INTERVAL = 0.0005
# The build thread's nice value (Linux, per thread): the serving thread comes first.
_BUILD_NICENESS = 10


class SceneBuilder:
    """Builds a set of served scenes in a background thread, one build at a time.

    Args:
        build: Loads and builds the scenes (raises on any scene that cannot be served).
    """

    def __init__(self, build: Callable[[], list[ServedScene]]) -> None:
        self._build = build
        self._thread: threading.Thread | None = None
        self._result: list[ServedScene] | None = None
        self._switch_interval = sys.getswitchinterval()

    def start(self) -> bool:
        """Start a build; False (and nothing started) when one is already under way."""
        if self._thread is not None:
            return False
        self._result = None
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, _BUILD_SWITCH_INTERVAL))
        self._thread = threading.Thread(target=self._run, name="membrane-reload", daemon=True)
        self._thread.start()
        return True

    def take(self) -> list[ServedScene] | None:
        """The built scenes once the build has finished successfully, else None (a failed
        build is logged and forgotten: the scenes being served stay)."""
        thread = self._thread
        if thread is None or thread.is_alive():
            return None
        self._thread = None
        sys.setswitchinterval(self._switch_interval)
        result, self._result = self._result, None
        return result

    def build_now(self) -> list[ServedScene] | None:
        """Build in the calling thread: the scenes, or None when one cannot be served (logged;
        the scenes being served stay)."""
        started = time.monotonic()
        try:
            built = self._build()
        except Exception as exc:  # a scene that cannot be served: keep the old ones
            logger.error("reload failed, still serving the previous scenes: %s", exc)
            return None
        logger.info("reload: new scenes built in %.2f s", time.monotonic() - started)
        return built

    def _run(self) -> None:
        _lower_this_threads_priority()
        self._result = self.build_now()


def _lower_this_threads_priority() -> None:
    """Make the calling thread yield the CPU to the serving thread (Linux: a thread's own nice
    value; elsewhere nothing). On a machine with few cores, a build that competes at equal
    priority can keep the serving thread off the CPU for a scheduler slice or more."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), _BUILD_NICENESS)
    except (AttributeError, OSError) as exc:
        logger.debug("reload: build thread priority unchanged: %s", exc)


def describe_changes(old: Mapping[str, ServedScene], new: Sequence[ServedScene]) -> str:
    """One line naming, per scene, what a reload changed (the ``describe`` fields that differ)."""
    parts = []
    for served in new:
        before = old.get(served.name)
        if before is None:
            parts.append(f"{served.name} (added)")
        elif before.revision == served.revision:
            parts.append(f"{served.name} (unchanged)")
        else:
            fields = _changed_fields(before.describe(), served.describe())
            parts.append(
                f"{served.name} (revision {before.revision} -> {served.revision}: "
                f"{', '.join(fields) or 'content'})"
            )
    names = {served.name for served in new}
    parts += [f"{name} (removed)" for name in old if name not in names]
    return "; ".join(parts)


def _changed_fields(before: Mapping[str, Any], after: Mapping[str, Any]) -> list[str]:
    keys = [key for key in after if key != "revision"]
    return [key for key in keys if not _same(before.get(key), after.get(key))]


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return bool(np.array_equal(a, b))
    return bool(a == b)
