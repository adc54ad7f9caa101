"""Live tables kept between runs, in the user's cache directory, never trusted unverified.

Building a model's live tables (modes, footprints, static correction: ``tables``) takes
seconds; reading them back takes milliseconds. An entry is keyed by a SHA-256 of everything
that decides its contents: the mesh's points and triangles, the model, the supports, the
element, the mode count, the lattice, the radii, the correction, this module's ``FORMAT`` and
the sources of the ``fem`` package (the package version is the same on every commit, so it
cannot tell two builds apart). An entry whose stored key or content digest does not match is
rebuilt (and replaced), never used.

Where: ``$MEMBRANE_CACHE_DIR/fem`` if set, else platformdirs' user cache directory
(``~/.cache/membrane/fem`` on Linux). Writes go to a temporary file renamed into place, so
a reader never sees half an entry. "Cold" means an empty cache.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import tempfile
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from membrane_models.fem.assembly import ElementName, assemble
from membrane_models.fem.geometry import Domain
from membrane_models.fem.interpolation import CentreGrid
from membrane_models.fem.modal import modes as lowest_modes
from membrane_models.fem.models import Model
from membrane_models.fem.tables import FootprintTables, LiveTables, live_tables
from membrane_models.live.tabulated_basis import frozen

__all__ = [
    "FORMAT",
    "CacheUse",
    "TableCache",
    "cache_directory",
    "cached_tables",
    "recorded_entries",
    "table_key",
]

logger = logging.getLogger(__name__)
FORMAT = 2  # bump when the tables' meaning changes without a change to the fem sources
_SOURCES = Path(__file__).resolve().parent


@dataclass(frozen=True)
class CacheUse:
    """An entry a build used: its file's name, and whether it was built (else found)."""

    name: str
    built: bool


# The open ``recorded_entries`` blocks' lists (a stack: blocks may nest).
_RECORDERS: list[list[CacheUse]] = []


@contextmanager
def recorded_entries() -> Iterator[list[CacheUse]]:
    """The entries any ``TableCache`` of this process finds or stores inside the block, in
    order (``membrane caches`` reports them and checks they are where the command looks)."""
    used: list[CacheUse] = []
    _RECORDERS.append(used)
    try:
        yield used
    finally:  # by identity: two blocks' lists may be equal
        del _RECORDERS[next(i for i, r in enumerate(_RECORDERS) if r is used)]


def _record(path: Path, built: bool) -> None:
    for used in _RECORDERS:
        used.append(CacheUse(path.name, built))


def cache_directory(root: Path | None = None) -> Path:
    """The tables' folder under the caches' ``root``: by default ``$MEMBRANE_CACHE_DIR/fem``,
    else the user's cache directory's ``membrane/fem``."""
    if root is None:
        given = os.environ.get("MEMBRANE_CACHE_DIR")
        root = Path(given) if given else Path(platformdirs.user_cache_dir("membrane"))
    return root / "fem"


def source_digest() -> str:
    """SHA-256 of the fem package's sources (their names and bytes)."""
    digest = hashlib.sha256()
    for path in sorted(_SOURCES.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def table_key(
    domain: Domain,
    model: Model,
    supports: Mapping[str, str] | str,
    element: str | None,
    count: int,
    lattice: Sequence[int],
    radii: Sequence[float],
    static_correction: bool,
) -> str:
    """The entry's key (module docstring)."""
    digest = hashlib.sha256()
    described = {
        "format": FORMAT,
        "sources": source_digest(),
        "model": [type(model).__name__, {f.name: getattr(model, f.name) for f in fields(model)}],
        "supports": supports if isinstance(supports, str) else sorted(supports.items()),
        "element": element,
        "modes": int(count),
        "lattice": [int(n) for n in lattice],
        "radii": [float(r).hex() for r in radii],
        "correction": bool(static_correction),
        "parts": sorted((name, len(facets)) for name, facets in domain.parts.items()),
        "curves": sorted((name, repr(curve)) for name, curve in domain.curves.items()),
    }
    digest.update(json.dumps(described, sort_keys=True, default=repr).encode())
    mesh = domain.mesh
    digest.update(np.ascontiguousarray(mesh.p, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(mesh.t, dtype=np.int64).tobytes())
    for name in sorted(domain.parts):
        digest.update(np.ascontiguousarray(domain.parts[name], dtype=np.int64).tobytes())
    return digest.hexdigest()


class TableCache:
    """Live tables by key in ``directory`` (default ``cache_directory()``)."""

    def __init__(self, directory: Path | None = None) -> None:
        self.directory = directory if directory is not None else cache_directory()

    def path(self, key: str) -> Path:
        return self.directory / f"{key[:32]}.npz"

    def load(self, key: str) -> LiveTables | None:
        """The entry of ``key``, or None when absent, unreadable or not matching its key."""
        entry = self.load_entry(key)
        return None if entry is None else _tables(*entry)

    def load_entry(self, key: str) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
        """Any entry's metadata and arrays (another table kind's: ``reduced_cache``), or None
        when absent, unreadable or not matching its key."""
        path = self.path(key)
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as stored:
                arrays = {name: stored[name] for name in stored.files}
            meta = json.loads(bytes(arrays.pop("meta")).decode())
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
            logger.warning("fem cache entry %s unreadable (%s): rebuilding it", path, error)
            return None
        if meta.get("key") != key or meta.get("digest") != _digest(arrays):
            logger.warning("fem cache entry %s does not match its key: rebuilding it", path)
            return None
        _record(path, built=False)
        return meta, arrays

    def store(self, key: str, tables: LiveTables) -> Path:
        """Write the entry of ``key`` (atomically: a temporary file renamed into place)."""
        arrays, meta = _arrays(tables)
        return self.store_entry(key, arrays, meta)

    def store_entry(self, key: str, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Path:
        """Write any entry's arrays and metadata under ``key`` (atomically)."""
        meta = dict(meta)
        meta.update(key=key, digest=_digest(arrays))
        self.directory.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        stored = {"meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays}
        np.savez(buffer, **stored)  # type: ignore[arg-type]  # numpy's stub types **kwds as bool
        handle, temporary = tempfile.mkstemp(dir=self.directory, suffix=".tmp")
        try:
            with os.fdopen(handle, "wb") as out:
                out.write(buffer.getvalue())
            os.replace(temporary, self.path(key))
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise
        _record(self.path(key), built=True)
        return self.path(key)


def cached_tables(
    domain: Domain,
    model: Model,
    supports: Mapping[str, str] | str,
    *,
    count: int,
    lattice: tuple[int, int],
    radii: Sequence[float],
    element: ElementName | None = None,
    static_correction: bool = True,
    cache: TableCache | None = None,
) -> tuple[LiveTables, bool]:
    """The live tables of ``count`` modes of ``model`` on ``domain``: from the cache when it
    holds them (True), else built and stored (False)."""
    store = cache if cache is not None else TableCache()
    key = table_key(domain, model, supports, element, count, lattice, radii, static_correction)
    found = store.load(key)
    if found is not None:
        return found, True
    system = assemble(domain, model, supports, element)
    tables = live_tables(
        system, lowest_modes(system, count), lattice, radii, static_correction=static_correction
    )
    store.store(key, tables)
    return tables, False


def _digest(arrays: Mapping[str, np.ndarray]) -> str:
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _arrays(tables: LiveTables) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    arrays: dict[str, np.ndarray] = {
        "omega": tables.omega,
        "shapes": tables.shapes,
        "inside": tables.inside,
        "boundary": tables.boundary,
    }
    prints = []
    for i, fp in enumerate(tables.footprints):
        arrays[f"modal_force_{i}"] = fp.modal_force
        if fp.own is not None:
            arrays[f"own_{i}"] = fp.own
        if fp.field is not None:
            arrays[f"field_{i}"] = fp.field
        own_grid = None if fp.own_grid is None else asdict(fp.own_grid)
        grids = {"grid": asdict(fp.grid), "cross_grid": asdict(fp.cross_grid), "own_grid": own_grid}
        prints.append({"radius": fp.radius, **grids})
    for (i, j), values in tables.cross.items():
        arrays[f"cross_{i}_{j}"] = values
    meta = {
        "format": FORMAT,
        "lattice": list(tables.lattice),
        "lower": list(tables.lower),
        "upper": list(tables.upper),
        "footprints": prints,
        "cross": [list(pair) for pair in tables.cross],
    }
    return arrays, meta


def _grid(stored: Mapping[str, Any]) -> CentreGrid:
    origin, shape = stored["origin"], stored["shape"]
    return CentreGrid(
        (float(origin[0]), float(origin[1])),
        float(stored["spacing"]),
        (int(shape[0]), int(shape[1])),
    )


def _tables(meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> LiveTables:
    footprints = tuple(
        FootprintTables(
            float(fp["radius"]),
            _grid(fp["grid"]),
            frozen(arrays[f"modal_force_{i}"]),
            frozen(arrays[f"own_{i}"]) if f"own_{i}" in arrays else None,
            frozen(arrays[f"field_{i}"]) if f"field_{i}" in arrays else None,
            _grid(fp["cross_grid"]),
            None if fp["own_grid"] is None else _grid(fp["own_grid"]),
        )
        for i, fp in enumerate(meta["footprints"])
    )
    cross = {(int(i), int(j)): frozen(arrays[f"cross_{i}_{j}"]) for i, j in meta["cross"]}
    return LiveTables(
        (int(meta["lattice"][0]), int(meta["lattice"][1])),
        (float(meta["lower"][0]), float(meta["lower"][1])),
        (float(meta["upper"][0]), float(meta["upper"][1])),
        frozen(arrays["omega"]),
        frozen(arrays["shapes"]),
        frozen(arrays["inside"]),
        frozen(arrays["boundary"]),
        footprints,
        cross,
    )
