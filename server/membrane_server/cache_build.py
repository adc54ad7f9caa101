"""Building the FEM caches scenes need before they are served, for many materials at once.

A physical scene's first load builds its tissue's tables (modes, footprints, static
correction; a nonlinear scene's reduced plate too): seconds to a minute of a core each, then
milliseconds from the cache (``membrane_models.fem.cache``). A study over materials (Young's
modulus, thickness, supports...) is one such build per variant, each independent of the others:
a batch of jobs for an executor (``membrane_models.executors``: one after another here, or as Ray
tasks). A job loads its variant exactly as ``membrane serve`` would, so what it stores is what a
server of that variant reads, under the same keys.

The jobs write into one cache directory, which on a cluster must be one every node sees (a
shared filesystem): each job says which entries it found or built, and the command checks them
in its own view of the directory, so that entries left on a worker's own disk are an error, not
a silent miss at serving time.
"""

from __future__ import annotations

import copy
import itertools
import os
import time
import tomllib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from membrane_errors import UserError
from membrane_models.fem.cache import CacheUse, cache_directory, recorded_entries
from membrane_server.scene import SceneError, load_scene, scene_from_dict

__all__ = [
    "SceneCaches",
    "Variant",
    "build_scene_caches",
    "missing_entries",
    "parse_vary",
    "variants",
]

_CACHE_ROOT = "MEMBRANE_CACHE_DIR"  # the caches' root, read by fem.cache.cache_directory


@dataclass(frozen=True)
class Variant:
    """One scene to build: its data (parsed TOML, the variant's values set), where its file is
    (relative mesh paths resolve against it) and what was varied, in words."""

    data: dict[str, Any]
    source: str
    label: str


@dataclass(frozen=True)
class SceneCaches:
    """What one variant's build did: each cache entry it used (found or built), its seconds."""

    label: str
    tissue: str | None
    entries: tuple[CacheUse, ...]
    seconds: float


def parse_vary(text: str) -> tuple[tuple[str, ...], list[Any]]:
    """``tissue.youngs_modulus=1e6,2e6`` as (the dotted key's parts, its values as TOML reads
    them): the values are read as the items of one TOML array, so that a value may be a list
    or a quoted string with commas of its own (``tissue.radii=[0.0,0.005],[0.0,0.003]``).
    Raises SceneError on anything else."""
    key, sep, values = text.partition("=")
    parts = tuple(part.strip() for part in key.split("."))
    if not sep or not all(parts) or not values.strip():
        example = "tissue.thickness=0.002,0.003"
        raise SceneError(f"--vary takes KEY=V1,V2,... (e.g. {example}), got {text!r}")
    try:
        parsed: list[Any] = tomllib.loads(f"v = [{values}]")["v"]
    except tomllib.TOMLDecodeError:
        raise SceneError(f"--vary {key}: {_first_unreadable(values)}") from None
    return parts, parsed


def _first_unreadable(values: str) -> str:
    """Why ``values`` is not a list of TOML values, naming the first item that is not one
    (items split at the commas outside brackets and quotes)."""
    items, depth, quote, start = [], 0, "", 0
    for index, char in enumerate(values):
        if quote:
            quote = "" if char == quote else quote
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char in "]}":
            depth -= 1
        elif char == "," and depth == 0:
            items.append(values[start:index])
            start = index + 1
    items.append(values[start:])
    for item in items:
        if not item.strip():
            return f"an empty value between commas in {values!r}"
        try:
            tomllib.loads(f"v = {item.strip()}")
        except tomllib.TOMLDecodeError:
            return f'{item.strip()!r} is not a TOML value (a string takes quotes: "clamped")'
    return f"{values!r} is not a comma-separated list of TOML values"


def variants(scenes: Sequence[str], vary: Sequence[str]) -> list[Variant]:
    """Every scene under every combination of the ``--vary`` values (a scene unvaried when
    there are none), each validated as a scene before anything is built.

    Raises:
        SceneError: an unknown scene, a bad ``--vary``, a key the scene lacks, or a value
            the scene refuses (the message names it).
    """
    axes = [parse_vary(text) for text in vary]
    keys = [".".join(parts) for parts, _ in axes]
    for key in keys:
        if keys.count(key) > 1:
            raise SceneError(f"--vary {key} is given twice: give its values once, comma-separated")
    built = []
    for name in scenes:
        scene = load_scene(name)
        assert scene.source is not None  # load_scene's: a built-in scene's file or the user's
        base = tomllib.loads(scene.source.read_text(encoding="utf-8"))
        base.setdefault("name", scene.name)
        source = str(scene.source)
        for values in itertools.product(*(axis[1] for axis in axes)):
            data = copy.deepcopy(base)
            words = [scene.name]
            for (parts, _), value in zip(axes, values, strict=True):
                _set(data, parts, value, scene.name)
                words.append(f"{'.'.join(parts)}={value}")
            scene_from_dict(data, Path(source))  # a value the scene refuses is refused here
            built.append(Variant(data, source, " ".join(words)))
    return built


def build_scene_caches(variant: Variant, cache_root: str) -> SceneCaches:
    """Load ``variant`` as a server would, its FEM caches in ``cache_root`` (found or built
    and stored there): a job for an executor. BLAS is held to one thread, so that a build's
    floating point does not depend on how many threads the process it ran in had."""
    from membrane_server.served import ServedScene

    scene = scene_from_dict(variant.data, Path(variant.source))
    started = time.perf_counter()
    with _cache_root(cache_root), threadpool_limits(limits=1), recorded_entries() as entries:
        try:
            served = ServedScene.load(scene)
        except UserError as exc:  # say which variant (a build's own refusal, e.g. its size)
            raise UserError(f"{variant.label}: {exc}") from None
    close = getattr(served.live, "close", None)  # a worker it may hold
    if callable(close):
        close()
    tissue = None if scene.tissue is None else scene.tissue.name
    return SceneCaches(variant.label, tissue, tuple(entries), time.perf_counter() - started)


def missing_entries(caches: Sequence[SceneCaches], cache_root: Path) -> list[str]:
    """The entries the jobs say they used that this process cannot see in ``cache_root``."""
    folder = cache_directory(cache_root)
    return sorted({use.name for build in caches for use in build.entries} - _names(folder))


def _names(folder: Path) -> set[str]:
    return {path.name for path in folder.glob("*.npz")} if folder.is_dir() else set()


@contextmanager
def _cache_root(root: str) -> Iterator[None]:
    """``MEMBRANE_CACHE_DIR`` set to ``root`` for the block (a serial job runs in the
    command's own process: its environment is given back)."""
    before = os.environ.get(_CACHE_ROOT)
    os.environ[_CACHE_ROOT] = root
    try:
        yield
    finally:
        if before is None:
            del os.environ[_CACHE_ROOT]
        else:
            os.environ[_CACHE_ROOT] = before


def _set(data: dict[str, Any], parts: tuple[str, ...], value: Any, scene: str) -> None:
    """Set a dotted key (a field the scene does not know is refused by its validation)."""
    table = data
    for part in parts[:-1]:
        inner = table.get(part)
        if inner is None:
            raise SceneError(f"--vary {'.'.join(parts)}: scene {scene} has no [{part}] table")
        if not isinstance(inner, dict):
            raise SceneError(f"--vary {'.'.join(parts)}: {part!r} of scene {scene} is not a table")
        table = inner
    table[parts[-1]] = value
