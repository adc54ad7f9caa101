"""Reduced von Karman plates kept between runs, beside the linear engine's tables.

Building a reduced plate (``reduced_plate``: modes, an in-plane solve per pair of them, the
residual at the lattice points) takes seconds on the skin patch; reading it back takes
milliseconds. The modes are kept on every DOF too: a contact-adapted vector is made
orthogonal to these very vectors (``adapted_basis``), not to a new eigensolve's (whose
degenerate pairs may come out rotated). An entry is keyed as the tables are
(``cache.table_key``: the mesh, the model, the supports, the mode count, the lattice and the
fem sources) with the in-plane condition and ``FORMAT`` added, and is verified against its key
and content digest before use.
"""

from __future__ import annotations

import hashlib
import logging

import numpy as np

from membrane_models.fem.assembly import assemble
from membrane_models.fem.cache import TableCache, table_key
from membrane_models.fem.reduced_plate import ReducedPlate, reduce_plate
from membrane_models.fem.tissue import Tissue
from membrane_models.live.tabulated_basis import frozen

__all__ = ["FORMAT", "cached_reduced_plate"]

logger = logging.getLogger(__name__)
FORMAT = 2  # bump when a reduced plate's meaning changes without a change to the fem sources
_ARRAYS = ("omega", "quartic", "shapes", "residual", "movable", "boundary", "vectors")


def cached_reduced_plate(
    tissue: Tissue,
    lattice: tuple[int, int],
    modes: int,
    inplane: str,
    cache: TableCache | None = None,
) -> ReducedPlate:
    """The reduced plate of ``tissue`` on ``lattice``: from the cache, else built and stored."""
    store = cache if cache is not None else TableCache()
    key = _key(tissue, lattice, modes, inplane)
    entry = store.load_entry(key)
    if entry is not None and entry[0].get("kind") == "reduced-plate":
        meta, arrays = entry
        return ReducedPlate(
            frozen(arrays["omega"]),
            frozen(arrays["quartic"]),
            frozen(arrays["shapes"]),
            frozen(arrays["residual"]),
            frozen(arrays["movable"]),
            (int(meta["lattice"][0]), int(meta["lattice"][1])),
            (float(meta["lower"][0]), float(meta["lower"][1])),
            (float(meta["upper"][0]), float(meta["upper"][1])),
            int(meta["modes"]),
            frozen(arrays["boundary"]),
            frozen(arrays["vectors"]),
        )
    logger.info("building the reduced plate of %s (%d modes, in-plane %s)", tissue.name,
                modes, inplane)  # fmt: skip
    system = assemble(tissue.domain, tissue.model, tissue.supports, tissue.element)
    plate = reduce_plate(system, modes, lattice, inplane)
    arrays = {name: np.asarray(getattr(plate, name)) for name in _ARRAYS}
    meta = {
        "kind": "reduced-plate",
        "format": FORMAT,
        "lattice": list(plate.lattice),
        "lower": list(plate.lower),
        "upper": list(plate.upper),
        "modes": plate.modes,
    }
    store.store_entry(key, arrays, meta)
    return plate


def _key(tissue: Tissue, lattice: tuple[int, int], modes: int, inplane: str) -> str:
    base = table_key(tissue.domain, tissue.model, tissue.supports, tissue.element, modes,
                     lattice, (), False)  # fmt: skip
    return hashlib.sha256(f"reduced-plate:{FORMAT}:{inplane}:{base}".encode()).hexdigest()
