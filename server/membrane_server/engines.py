"""Live engines by kind: the ``membrane.engines`` entry-point group.

A scene's ``[live]`` table names its engine kind (``engine = "modal"`` by default). Each entry of
the group is a callable ``(problem, lattice, dt, options) -> LiveEngine``; the built-in
``modal`` one is ``membrane_models.live.build_modal_engine``. A package (or a test) adds a kind
by declaring an entry point, without editing the server: the server holds every engine as a
``LiveEngine`` and learns what it takes (``inputs``) and what to say of it (``describe()``)
from the engine itself.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from importlib.metadata import entry_points
from typing import Any

from membrane_errors import UserError
from membrane_models.live import LiveEngine
from membrane_models.problems import Problem

__all__ = ["ENGINE_GROUP", "EngineFactory", "UnknownEngine", "build_engine", "engine_kinds"]

ENGINE_GROUP = "membrane.engines"
# (what the scene models: a dimensionless Problem, or a physical Tissue; lattice; dt; options)
EngineFactory = Callable[[Any, tuple[int, ...], float, Mapping[str, object]], LiveEngine[Any]]


class UnknownEngine(UserError):
    """A scene names an engine kind no installed package registers."""


@functools.cache
def engine_kinds() -> dict[str, EngineFactory]:
    """The registered kinds (read once per process: entry points do not change while serving)."""
    kinds: dict[str, EngineFactory] = {}
    for entry in entry_points(group=ENGINE_GROUP):
        kinds.setdefault(entry.name, entry.load())
    return kinds


def build_engine(
    kind: str,
    problem: Problem | object,
    lattice: tuple[int, ...],
    dt: float,
    options: Mapping[str, object],
) -> LiveEngine[Any]:
    """The engine of ``kind`` for a scene (its errors are the engine's ``LiveError``s).

    Raises:
        UnknownEngine: no package registers ``kind``.
    """
    factory = engine_kinds().get(kind)
    if factory is None:
        known = ", ".join(sorted(engine_kinds())) or "none"
        raise UnknownEngine(f"[live] engine {kind!r:.70} is not registered; registered: {known}")
    return factory(problem, lattice, dt, options)
