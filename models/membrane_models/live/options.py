"""A scene's ``[live]`` options as each engine kind checks them: the shared checks.

Each kind names its options (a mapping of option -> what it is, which ``describe``-style docs
and refusals quote) and reads them with these, so that an unknown key and a bad damping ratio
or mode count are refused alike by every kind. Bad values raise ``InvalidEngineSettings``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from membrane_models.live.errors import InvalidEngineSettings

__all__ = ["damping_option", "modes_option", "refuse_unknown"]


def refuse_unknown(options: Mapping[str, object], known: Mapping[str, str]) -> None:
    """Refuse the first option ``known`` does not name, listing those it does."""
    unknown = sorted(set(options) - set(known))
    if unknown:
        names = ", ".join(known)
        raise InvalidEngineSettings(f"unknown [live] option {unknown[0]!r:.40}; known: {names}")


def damping_option(options: Mapping[str, object]) -> float:
    """``damping``: a modal damping ratio in [0, 1) (default 0)."""
    damping = options.get("damping", 0.0)
    if isinstance(damping, bool) or not isinstance(damping, int | float):
        raise InvalidEngineSettings("[live] damping must be a number")
    if not (math.isfinite(damping) and 0.0 <= damping < 1.0):
        raise InvalidEngineSettings(f"[live] damping must be in [0, 1), got {damping:.6g}")
    return float(damping)


def modes_option(options: Mapping[str, object], most: int, default: int | None) -> int | None:
    """``modes``: an integer from 1 to ``most``, or ``default`` when not given."""
    modes = options.get("modes", default)
    if modes is None:
        return None
    if isinstance(modes, bool) or not isinstance(modes, int) or not 1 <= modes <= most:
        raise InvalidEngineSettings(f"[live] modes must be an integer from 1 to {most}")
    return modes
