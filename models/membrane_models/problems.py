"""The problems: wave equations on unit domains, as typed, validated objects.

Each problem is a frozen dataclass holding its physical parameters with the reference study's
defaults. ``make_problem(name, overrides)`` builds one from its registry name and ``NAME=VALUE``
overrides (strings, as typed at the command line); invalid values raise ``InvalidProblem``
(a ``ValueError``) with a message that names the parameter.

Conventions: nondimensional, spatial domain [0, 1] (the unit interval or the unit square), time
domain [0, t_end], fixed (zero) displacement on the whole boundary.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_errors import UserError

__all__ = [
    "PARAMETER_HELP",
    "PROBLEMS",
    "ForcedProblem",
    "InvalidProblem",
    "MembraneForced",
    "Problem",
    "StringForced",
    "StringPlucked",
    "make_problem",
    "time_bump",
]

FloatArray = NDArray[np.float64]


class InvalidProblem(UserError):
    """A problem name or parameter value that cannot be used."""


def time_bump(t: ArrayLike, a: float) -> FloatArray:
    """The forcing's time factor 4^a t^(a-1) (1-t)^(a-1) on [0, 1], zero outside.

    It peaks at t = 0.5 with the value 4 (for any a) and vanishes at both ends for a > 1.
    """
    t = np.asarray(t, dtype=np.float64)
    inside = (t >= 0.0) & (t <= 1.0)
    tc = np.where(inside, t, 0.5)  # keeps the powers finite where the mask is off
    # Computed through logs: 4^a overflows nothing, but t^(a-1) underflows gracefully this way.
    if a == 1.0:  # t^0 (1-t)^0 = 1, also at the ends (where 0 * log 0 would give NaN)
        return np.where(inside, 4.0, 0.0)
    with np.errstate(divide="ignore"):
        log_g = a * math.log(4.0) + (a - 1.0) * (np.log(tc) + np.log1p(-tc))
    return np.where(inside, np.exp(log_g), 0.0)


def _check_finite(problem: object) -> None:
    for f in fields(problem):  # type: ignore[arg-type]
        value = getattr(problem, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise InvalidProblem(f"{f.name} must be a finite number, got {value}")


def _check_positive(name: str, value: float) -> None:
    if not value > 0.0:
        raise InvalidProblem(f"{name} must be > 0, got {value}")


def _check_inside(name: str, value: float) -> None:
    if not 0.0 < value < 1.0:
        raise InvalidProblem(f"{name} must lie inside the domain (0, 1), got {value}")


@dataclass(frozen=True)
class Problem:
    """Common parts of every problem. Subclasses add their parameters and checks."""

    name: ClassVar[str]
    spatial_dims: ClassVar[int]
    equation: ClassVar[str]

    c: float
    t_end: float

    def __post_init__(self) -> None:
        _check_finite(self)
        _check_positive("c", self.c)
        _check_positive("t_end", self.t_end)
        self._check()

    def _check(self) -> None:
        """Problem-specific checks (override)."""

    @property
    def axes(self) -> tuple[str, ...]:
        """Names of the input axes, space first: ('x', 't') or ('x', 'y', 't')."""
        return ("x", "t") if self.spatial_dims == 1 else ("x", "y", "t")

    def parameters(self) -> dict[str, float]:
        """The parameters as plain data (for manifests and .npz files)."""
        return {k: float(v) for k, v in asdict(self).items()}

    def with_overrides(self, overrides: dict[str, str]) -> Problem:
        """A copy with ``NAME=VALUE`` overrides applied (values as strings or numbers).

        Names are case-insensitive, so ``C=10`` (the study's spelling) sets ``c``.
        """
        known = {f.name for f in fields(self)}
        parsed: dict[str, float] = {}
        for name, raw in overrides.items():
            key = name.strip().lower()
            if key not in known:
                raise InvalidProblem(
                    f"{self.name} has no parameter {key!r}; known: {', '.join(sorted(known))}"
                )
            try:
                parsed[key] = float(raw)
            except (TypeError, ValueError):
                raise InvalidProblem(f"{key} must be a number, got {raw!r}") from None
        return replace(self, **parsed)


@runtime_checkable
class ForcedProblem(Protocol):
    """A problem driven by f = profile(x[, y]) g_a(t): what training samples of its force.

    The forced string and membrane share it; their profiles take one coordinate array per space
    axis, hence ``force_profile(coords)`` with the axes as a sequence.
    """

    @property
    def h(self) -> float: ...

    @property
    def a(self) -> float: ...

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """The spatial profile at one coordinate array per space axis (broadcast together)."""
        ...


@dataclass(frozen=True)
class _ForcedMixin:
    """Parameters of the Gaussian-in-space, bump-in-time force f = -h exp(-k r^2) g_a(t)."""

    h: float = 1.0
    a: float = 8.9
    k: float = 400.0

    def _check_force(self) -> None:
        _check_positive("k", self.k)
        if self.a < 1.0:
            raise InvalidProblem(f"a must be >= 1 (the time factor t^(a-1) blows up), got {self.a}")


@dataclass(frozen=True)
class StringForced(_ForcedMixin, Problem):
    """u_tt = c^2 u_xx + f on x in [0, 1]; u = 0 at both ends; u = u_t = 0 at t = 0.

    f(x, t) = -h exp(-k (x - x0)^2) g_a(t), with g_a the time bump (zero outside t in [0, 1]).
    """

    name: ClassVar[str] = "string-forced"
    spatial_dims: ClassVar[int] = 1
    equation: ClassVar[str] = "u_tt = c^2 u_xx + f"

    c: float = 10.0
    t_end: float = 1.0
    x0: float = 0.8

    def _check(self) -> None:
        self._check_force()
        _check_inside("x0", self.x0)

    def force_space(self, x: ArrayLike) -> FloatArray:
        """The spatial profile -h exp(-k (x - x0)^2)."""
        x = np.asarray(x, dtype=np.float64)
        return -self.h * np.exp(-self.k * (x - self.x0) ** 2)

    def forcing(self, x: ArrayLike, t: ArrayLike) -> FloatArray:
        """f(x, t), broadcasting x against t."""
        return self.force_space(x) * time_bump(t, self.a)

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """``force_space`` with its one axis given as a sequence (``ForcedProblem``)."""
        (x,) = coords
        return self.force_space(x)


@dataclass(frozen=True)
class MembraneForced(_ForcedMixin, Problem):
    """z_tt = c^2 (z_xx + z_yy) + f on [0, 1]^2; z = 0 on the edges; z = z_t = 0 at t = 0.

    f(x, y, t) = -h exp(-k ((x - x0)^2 + (y - y0)^2)) g_a(t).
    """

    name: ClassVar[str] = "membrane-forced"
    spatial_dims: ClassVar[int] = 2
    equation: ClassVar[str] = "z_tt = c^2 (z_xx + z_yy) + f"

    c: float = 5.0
    t_end: float = 1.0
    x0: float = 0.8
    y0: float = 0.5

    def _check(self) -> None:
        self._check_force()
        _check_inside("x0", self.x0)
        _check_inside("y0", self.y0)

    def force_space(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """The spatial profile -h exp(-k ((x - x0)^2 + (y - y0)^2)), broadcasting x against y."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return -self.h * np.exp(-self.k * ((x - self.x0) ** 2 + (y - self.y0) ** 2))

    def forcing(self, x: ArrayLike, y: ArrayLike, t: ArrayLike) -> FloatArray:
        """f(x, y, t), broadcasting x, y and t."""
        return self.force_space(x, y) * time_bump(t, self.a)

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """``force_space`` with its two axes given as a sequence (``ForcedProblem``)."""
        x, y = coords
        return self.force_space(x, y)


@dataclass(frozen=True)
class StringPlucked(Problem):
    """u_tt = c^2 u_xx on x in [0, 1]; u = 0 at both ends; free vibration from a pluck.

    Initial shape: a triangle of height ``height`` with its apex at ``x0`` (kinked), or, when
    ``smoothing`` > 0, that triangle mollified by a Gaussian of standard deviation ``smoothing``
    (applied to its odd periodic extension, so the ends stay fixed). Zero initial velocity.
    The default t_end = 2 is one period (2 / c).
    """

    name: ClassVar[str] = "string-plucked"
    spatial_dims: ClassVar[int] = 1
    equation: ClassVar[str] = "u_tt = c^2 u_xx"

    c: float = 1.0
    t_end: float = 2.0
    height: float = 0.05
    x0: float = 0.3
    smoothing: float = 0.0

    def _check(self) -> None:
        _check_inside("x0", self.x0)
        if self.smoothing < 0.0:
            raise InvalidProblem(f"smoothing must be >= 0, got {self.smoothing}")

    def triangle(self, x: ArrayLike) -> FloatArray:
        """The unsmoothed pluck: rises linearly to ``height`` at x0, falls back to 0 at x = 1."""
        x = np.asarray(x, dtype=np.float64)
        rising = self.height * x / self.x0
        falling = self.height * (1.0 - x) / (1.0 - self.x0)
        return np.where(x <= self.x0, rising, falling)


# What each parameter means, for `membrane exact --help` and docs/SCENES.md (one line each).
PARAMETER_HELP: dict[str, str] = {
    "c": "wave speed",
    "t_end": "end of the time domain",
    "h": "force amplitude (the force is -h exp(-k r^2) g_a(t))",
    "a": "time bump exponent (>= 1; the force peaks at t = 0.5 and ends at t = 1)",
    "k": "force concentration: the Gaussian's exp(-k r^2)",
    "x0": "force centre on x (forced) or the pluck's apex (plucked), in (0, 1)",
    "y0": "force centre on y, in (0, 1)",
    "height": "pluck height",
    "smoothing": "pluck smoothing: Gaussian standard deviation (0: a sharp kink)",
}

# Registry: name -> (class, default overrides). The smoothed pluck is a named variant.
PROBLEMS: dict[str, tuple[type[Problem], dict[str, str]]] = {
    StringForced.name: (StringForced, {}),
    StringPlucked.name: (StringPlucked, {}),
    "string-plucked-smooth": (StringPlucked, {"smoothing": "0.02"}),
    MembraneForced.name: (MembraneForced, {}),
}


def make_problem(name: str, overrides: dict[str, str] | None = None) -> Problem:
    """Build a registered problem with its defaults, then apply ``overrides``."""
    try:
        cls, defaults = PROBLEMS[name]
    except KeyError:
        raise InvalidProblem(
            f"unknown problem {name!r}; known: {', '.join(sorted(PROBLEMS))}"
        ) from None
    default = cls()  # type: ignore[call-arg]  # every registered class defaults all its fields
    return default.with_overrides({**defaults, **(overrides or {})})
