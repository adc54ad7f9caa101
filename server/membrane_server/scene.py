"""Scene files: what a server serves (model, lattice, placement, time grid, evaluator, policy).

A scene is a TOML file validated with pydantic (fields: docs/SCENES.md). ``load_scene`` takes a
built-in scene's name (package data in ``membrane_server/scenes``) or a file path; every error is
a ``SceneError`` (a ValueError) whose message names the field and the reason.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictFloat,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from membrane_client.protocol import MAX_LATTICE_POINTS, MAX_LIVE_POINTS
from membrane_errors import UserError
from membrane_models.problems import PROBLEMS, make_problem
from membrane_server.tissue_table import TissueTable

__all__ = [
    "DEFAULT_TABLE_MAX_BYTES",
    "MAX_STEPS",
    "SCENES_DIR",
    "EvaluatorKind",
    "Lattice",
    "LiveSettings",
    "Placement",
    "Scene",
    "SceneError",
    "builtin_scenes",
    "load_scene",
    "problem_overrides",
]

SCENES_DIR = Path(str(resources.files("membrane_server") / "scenes"))
DEFAULT_TABLE_MAX_BYTES = 256 * 1024 * 1024
# A duration counts as a whole number of steps when it is within this many steps of one.
_STEP_TOLERANCE = 1e-9
# Most steps in a scene: every step index (and k * dt's position) is exact in float64.
MAX_STEPS = 2**53 - 1
# A step must span this many float64 numbers at the scene's latest time, so that a time can be
# snapped to its step (and interpolated within it) to about a thousandth of a step.
_MIN_ULPS_PER_STEP = 1024

EvaluatorKind = Literal["network", "separable", "table", "exact"]
_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$"
_NAME_RULE = "letters, digits and _.- (a letter or digit first), at most 64 characters"


class SceneError(UserError):
    """A scene that cannot be read, validated or served."""


class _Strict(BaseModel):
    # Unknown keys are typos; NaN and infinities are never meaningful in a scene. Strict types:
    # `dt = "0.01"` or `nx = 20.0` is a slip to point out, not to convert (an int is still a
    # number wherever a float belongs).
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


class Lattice(_Strict):
    """Where the displacement is evaluated: a regular grid or an explicit list of points.

    A grid has ``nx`` points along x (and ``ny`` along y for a membrane), end points included,
    over the model's spatial domain. Grid points are ordered x-major: point ``i * ny + j`` is
    (x_i, y_j), so a frame reshaped to (nx, ny) is indexed [i, j].
    """

    nx: int | None = Field(default=None, ge=1, le=MAX_LATTICE_POINTS)
    ny: int | None = Field(default=None, ge=1, le=MAX_LATTICE_POINTS)
    points: list[list[float]] | None = Field(default=None, min_length=1)

    @field_validator("points")
    @classmethod
    def _rows_alike(cls, points: list[list[float]] | None) -> list[list[float]] | None:
        if points is None:
            return None
        width = len(points[0])
        if width not in (1, 2):
            raise ValueError(f"each point needs 1 (x) or 2 (x, y) coordinates, got {width}")
        for index, row in enumerate(points):
            if len(row) != width:
                raise ValueError(f"point {index} has {len(row)} coordinates, point 0 has {width}")
        if len(points) > MAX_LATTICE_POINTS:
            raise ValueError(f"{len(points)} points, more than the limit {MAX_LATTICE_POINTS}")
        return points

    @model_validator(mode="after")
    def _one_form(self) -> Lattice:
        if self.points is not None:
            if self.nx is not None or self.ny is not None:
                raise ValueError("give either nx[, ny] or points, not both")
            return self
        if self.nx is None:
            raise ValueError("give nx (and ny for a membrane) or a list of points")
        if self.nx * (self.ny or 1) > MAX_LATTICE_POINTS:
            raise ValueError(
                f"nx * ny = {self.nx * (self.ny or 1)} points, more than the limit "
                f"{MAX_LATTICE_POINTS}"
            )
        return self

    @property
    def dims(self) -> int:
        """Number of spatial coordinates per point (1 or 2)."""
        if self.points is not None:
            return len(self.points[0])
        return 1 if self.ny is None else 2

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of a frame: (nx,), (nx, ny), or (n,) for a point list."""
        if self.points is not None:
            return (len(self.points),)
        assert self.nx is not None  # guaranteed by _one_form
        return (self.nx,) if self.ny is None else (self.nx, self.ny)

    def coordinates(self, bounds: Sequence[tuple[float, float]]) -> np.ndarray:
        """(n, d) float64 coordinates, a grid spanning ``bounds`` (one (low, high) per axis).

        Raises:
            SceneError: The lattice's dimension differs from the model's, or a listed point lies
                outside ``bounds``.
        """
        if len(bounds) != self.dims:
            raise SceneError(
                f"lattice: the model has {len(bounds)} space axes, the lattice {self.dims} "
                f"({'give nx and ny' if len(bounds) == 2 else 'give nx only'})"
            )
        if self.points is not None:
            points = np.asarray(self.points, dtype=np.float64)
            for axis, (low, high) in enumerate(bounds):
                outside = np.flatnonzero((points[:, axis] < low) | (points[:, axis] > high))
                if outside.size:
                    raise SceneError(
                        f"lattice.points.{int(outside[0])}: {self.points[outside[0]]} lies "
                        f"outside the model's domain [{low}, {high}] on axis {axis}"
                    )
            return points
        counts = self.shape
        axes = [np.linspace(low, high, n) for (low, high), n in zip(bounds, counts, strict=True)]
        grids = np.meshgrid(*axes, indexing="ij")
        return np.stack([g.reshape(-1) for g in grids], axis=1)


class Placement(_Strict):
    """Where the lattice sits in the simulator's world, and how displacements show.

    Lattice coordinate u (and v) times ``size`` runs along the two world axes other than
    ``axis`` (x, y, z order); a sphere rests at ``origin`` plus that and moves by ``scale * z``
    along ``axis``.
    """

    # TOML has arrays, not tuples: the tuple itself is lax (a list converts), its numbers strict.
    origin: tuple[StrictFloat, StrictFloat, StrictFloat] = Field(
        default=(0.0, 0.0, 0.0), strict=False
    )
    size: float = Field(default=1.0, gt=0.0)
    scale: float = 1.0
    axis: Literal["x", "y", "z"] = "z"


class LiveSettings(BaseModel):
    """A live scene's engine: sessions step it with loads and probes (docs/LIVE.md).

    ``engine`` names a kind registered in the ``membrane.engines`` entry-point group (built in:
    ``modal``); every other key is that engine's option, checked by the engine when the scene
    is built (``options``), so a new kind brings its settings without a change here.
    """

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False, strict=True)

    engine: str = Field(default="modal", pattern=_NAME_PATTERN)

    @property
    def options(self) -> dict[str, Any]:
        """The engine's options: the table's keys but ``engine``."""
        return dict(self.model_extra or {})


class Scene(_Strict):
    """One served scene (field reference: docs/SCENES.md)."""

    name: str = Field(pattern=_NAME_PATTERN)
    description: str = ""
    # A film scene names a dimensionless problem or a trained model and how to answer it; a
    # physical scene names its tissue instead ([tissue], SI units) and has no film.
    model: str = ""
    evaluator: EvaluatorKind | None = None
    tissue: TissueTable | None = None
    # The problem's own parameters (wave speed c, force place x0/y0, amplitude h, ...), for an
    # exact scene: checked as `membrane exact --set` checks them.
    parameters: dict[str, float] | None = None
    lattice: Lattice
    placement: Placement = Placement()
    dt: float = Field(gt=0.0)
    duration: float = Field(gt=0.0)
    start_offset: float = 0.0
    snapping: Literal["nearest", "linear"] = "nearest"
    policy: Literal["error", "clamp", "hold"] = "hold"
    table_max_bytes: int = Field(default=DEFAULT_TABLE_MAX_BYTES, gt=0)
    live: LiveSettings | None = None
    # Whether `query` answers a film; a live scene that gives no `duration` has none (its
    # `query` answers the rest shape and nothing is built for it at load).
    film: bool = True
    # Where the file was read from: relative model paths are resolved against its folder.
    source: Path | None = Field(default=None, exclude=True)

    @model_validator(mode="before")
    @classmethod
    def _live_without_film(cls, data: Any) -> Any:
        # A live scene without a duration (a physical scene always) has no film: its time grid
        # is its step alone and `query` answers its rest shape.
        if not (isinstance(data, dict) and "dt" in data and "duration" not in data):
            return data
        if "tissue" in data or "live" in data:
            return {**data, "duration": data["dt"], "film": False}
        return data

    @model_validator(mode="after")
    def _model_or_tissue(self) -> Scene:
        if self.tissue is None:
            if not self.model or self.evaluator is None:
                raise ValueError(
                    "give model and evaluator (a film scene) or a [tissue] table (a physical "
                    "live scene)"
                )
            return self
        if self.model or self.evaluator is not None or self.parameters is not None:
            raise ValueError(
                "a [tissue] scene names no model, evaluator or parameters: the tissue is its model"
            )
        if self.live is None:
            raise ValueError("a [tissue] scene is live: add a [live] table (its engine: fem)")
        if self.lattice.ny is None or self.lattice.points is not None:
            raise ValueError("lattice: a [tissue] scene needs nx and ny (a grid over the tissue)")
        if self.film:
            raise ValueError("duration: a [tissue] scene has no film; leave duration out")
        return self

    @model_validator(mode="after")
    def _film_is_stated_by_duration(self) -> Scene:
        if not self.film and (self.live is None or self.duration != self.dt):
            raise ValueError(
                "film: only a live scene goes without a film, by leaving its duration out"
            )
        return self

    @field_validator("duration")
    @classmethod
    def _whole_steps(cls, duration: float, info: ValidationInfo) -> float:
        dt = info.data.get("dt")
        if dt is None:  # dt itself failed validation; that error is reported
            return duration
        ratio = duration / dt
        if not math.isfinite(ratio) or ratio > MAX_STEPS:  # dt = 5e-324 overflows the ratio
            raise ValueError(
                f"{duration} s of dt ({dt}) steps is {ratio:.6g} steps, more than the limit "
                f"{MAX_STEPS} (2^53 - 1: step indices exact in float64)"
            )
        if round(ratio) < 1 or abs(ratio - round(ratio)) > _STEP_TOLERANCE * max(1.0, ratio):
            raise ValueError(
                f"must be a whole number (>= 1) of dt ({dt}) steps, got {ratio:.6g} steps"
            )
        return duration

    @field_validator("parameters")
    @classmethod
    def _problem_parameters(
        cls, parameters: dict[str, float] | None, info: ValidationInfo
    ) -> dict[str, float] | None:
        if parameters is None:
            return None
        model, evaluator = info.data.get("model"), info.data.get("evaluator")
        if not model or evaluator is None:  # their own errors are reported
            return parameters
        if evaluator != "exact" or model not in PROBLEMS:
            raise ValueError(
                "only for evaluator 'exact' with a problem as model "
                f"({', '.join(sorted(PROBLEMS))}): a trained model's parameters are the ones "
                "it was trained on (train one with `membrane train --set`)"
            )
        make_problem(model, problem_overrides(parameters))  # InvalidProblem names the parameter
        return parameters

    @model_validator(mode="after")
    def _live_lattice(self) -> Scene:
        if self.live is None:
            return self
        lattice = self.lattice
        if lattice.points is not None or min(lattice.shape) < 3:
            raise ValueError("live: needs a grid lattice (nx, and ny on a membrane), >= 3 per axis")
        if math.prod(lattice.shape) > MAX_LIVE_POINTS:
            raise ValueError(
                f"live: {math.prod(lattice.shape)} points, more than the live limit "
                f"{MAX_LIVE_POINTS} (100 x 100)"
            )
        return self

    @model_validator(mode="after")
    def _distinct_step_times(self) -> Scene:
        # Step times are start_offset + k * dt in float64: past some offset, consecutive steps
        # round to the same time (or too few distinct times to snap to), and queries would
        # silently get the wrong step.
        latest = max(abs(self.start_offset), abs(self.start_offset + self.duration))
        resolution = _MIN_ULPS_PER_STEP * math.ulp(latest)
        if self.dt < resolution:
            raise ValueError(
                f"start_offset: step times near {latest:.6g} s are float64 numbers "
                f"{math.ulp(latest):.3g} s apart; dt ({self.dt} s) must be at least "
                f"{resolution:.3g} s there (or start_offset smaller) so that steps stay distinct"
            )
        return self

    @property
    def where(self) -> str:
        """How error messages name this scene: its file when it has one, else its name."""
        return f"scene {self.source}" if self.source is not None else f"scene {self.name}"

    def error(self, exc: Exception) -> SceneError:
        """``exc`` as a SceneError that names this scene's file (once), for errors raised where
        the scene is not known (a lattice, an evaluator's budget)."""
        message = str(exc)
        if message.startswith(f"{self.where}:"):
            return SceneError(message)
        stale = f"scene {self.name}: "  # named by its name only: the file says more
        return SceneError(f"{self.where}: {message.removeprefix(stale)}")

    @property
    def last_step(self) -> int:
        """N: the frames are steps 0 .. N."""
        return round(self.duration / self.dt)

    @property
    def steps(self) -> int:
        """Number of frames, N + 1."""
        return self.last_step + 1

    def model_path(self) -> Path | None:
        """The model as a path, when ``model`` names a file (resolved against the scene file)."""
        path = Path(self.model)
        if path.suffix not in (".json", ".onnx"):
            return None
        if not path.is_absolute() and self.source is not None:
            path = self.source.parent / path
        return path


def problem_overrides(parameters: dict[str, float] | None) -> dict[str, str]:
    """A scene's ``[parameters]`` as ``make_problem`` overrides (``repr`` keeps every digit)."""
    return {name: repr(float(value)) for name, value in (parameters or {}).items()}


def builtin_scenes() -> list[str]:
    """Names of the scenes shipped with the server, sorted."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """Read and validate a scene: a built-in scene's name, or a TOML file's path.

    The scene's ``name`` defaults to the file's stem.

    Raises:
        SceneError: Unknown name, unreadable file, invalid TOML, or a field that fails
            validation (the message names it).
    """
    path = _scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SceneError(f"cannot read scene {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene {path}: invalid TOML: {exc}") from None
    if "name" not in data:
        _check_stem(path)
        data["name"] = path.stem
    return scene_from_dict(data, source=path.resolve())


def _check_stem(path: Path) -> None:
    """The file's stem is the default name: when it cannot be one, say how to name the scene."""
    if re.fullmatch(_NAME_PATTERN, path.stem):
        return
    fixed = re.sub(r"[^A-Za-z0-9_.\-]+", "-", path.stem).strip("_.-")[:64] or "scene"
    raise SceneError(
        f"scene {path.resolve()}: name: the file's stem {path.stem!r} is not a scene name "
        f"({_NAME_RULE}); set one in the file, e.g. name = {json.dumps(fixed)}"
    )


def scene_from_dict(data: dict[str, Any], source: Path | None = None) -> Scene:
    """Validate a scene given as plain data (parsed TOML); raises SceneError naming fields
    (and the file, when ``source`` is given)."""
    where = f"scene {source}" if source is not None else f"scene {data.get('name', '')}".rstrip()
    if "source" in data:
        raise SceneError(f"{where}: source: not a scene field")
    try:
        return Scene.model_validate({**data, "source": source})
    except ValidationError as exc:
        raise SceneError(f"{where}: {_describe_errors(exc)}") from None


def _scene_path(name_or_path: str | Path) -> Path:
    text = str(name_or_path)
    path = Path(text)
    if path.suffix == ".toml" or path.is_file() or "/" in text:
        return path
    builtin = SCENES_DIR / f"{text}.toml"
    if not builtin.is_file():
        known = ", ".join(builtin_scenes()) or "none"
        raise SceneError(f"unknown scene {text!r}; built-in scenes: {known} (or give a .toml path)")
    return builtin


def _strict_type_hint(error: Any) -> str:
    """What a strict type refused, when it is a quoted number or a boolean (else nothing)."""
    value = error.get("input")
    if not str(error.get("type", "")).endswith("_type"):
        return ""
    if isinstance(value, bool):
        return f", got the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f", got the string {value!r} (numbers go without quotes)"
    return ""


def _describe_errors(exc: ValidationError) -> str:
    parts = []
    for error in exc.errors(include_url=False):
        location = ".".join(str(part) for part in error["loc"])
        message = str(error["msg"]).removeprefix("Value error, ")
        message += _strict_type_hint(error)
        # A whole-scene check names its fields in its message: no location to add.
        parts.append(f"{location}: {message}" if location else message)
    return "; ".join(parts)
