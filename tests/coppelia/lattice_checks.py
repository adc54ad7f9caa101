"""What the lattice tests share: a lattice on a given connection, and where its spheres should
be (from describe's fields, not the client's own placement code)."""

from __future__ import annotations

from typing import Any

import numpy as np

from membrane_client import Client, SceneInfo
from membrane_coppelia.lattice import SphereLattice
from membrane_coppelia.link import SimulatorLink
from membrane_coppelia.standin import FakeScene

__all__ = ["SIM_TIMEOUT", "expected_world", "lattice_on", "positions_at_stop"]

SIM_TIMEOUT = 2.0


def lattice_on(link: SimulatorLink, client: Client, **kwargs: Any) -> SphereLattice:
    return SphereLattice(link.sim, client, address=link.address, timeout=link.timeout, **kwargs)


def expected_world(info: SceneInfo, z: np.ndarray) -> np.ndarray:
    """Rest position plus scale * z along the axis, from describe's fields (not the client's)."""
    axis = "xyz".index(info.axis)
    lateral = [i for i in range(3) if i != axis]
    expected = np.tile(info.origin, (info.n_points, 1))
    for column in range(info.points.shape[1]):
        expected[:, lateral[column]] += info.size * info.points[:, column]
    expected[:, axis] += info.scale * z.reshape(-1).astype(np.float64)
    return expected


def positions_at_stop(scene: FakeScene, handles: list[int]) -> np.ndarray:
    return np.array([scene.positions_at_stop[h] for h in handles])
