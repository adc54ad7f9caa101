"""Live sessions: a robot's loads and probes reach the tissue, step by step (docs/PROTOCOL.md,
"Live sessions").

```python
with Client(address) as client, client.session("membrane-live") as session:
    frame = session.step(probes=[Probe((0.5, 0.5), depth=0.001, radius=0.05)])
    frame.probes[0].force, frame.positions()
```

Each Session has its own random id (the envelope's ``session``); one Client may hold several.
A step carries the index ``k`` it expects to take, so a step the Lazy Pirate re-sends is
answered from the server's stored reply, never applied twice. Each Session object also sends
its own random ``token`` on every live op: the server tells a re-send by the token, op and k,
so two clients whose request ids coincide are never taken for one client re-sending.
"""

from __future__ import annotations

import secrets
import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from membrane_client.errors import ProtocolError
from membrane_client.frame import SceneInfo
from membrane_client.protocol import Op, pack_array, unpack_array

if TYPE_CHECKING:
    from membrane_client.client import Client

__all__ = ["LiveFrame", "Load", "Probe", "ProbeReading", "Session"]


class Load(NamedTuple):
    """A Gaussian pressure of total ``force`` (> 0 pushes along +axis) centred ``at``."""

    at: tuple[float, ...]  # (x,) on a string, (x, y) on a membrane, problem units
    force: float
    radius: float  # > 0 on a membrane; 0 is a point force on a string

    def to_wire(self) -> dict[str, Any]:
        return {"at": [float(a) for a in self.at], "force": self.force, "radius": self.radius}


class Probe(NamedTuple):
    """A rigid tip whose face is ``depth`` >= 0 below the rest surface, pressing along -axis."""

    at: tuple[float, ...]
    depth: float
    radius: float

    def to_wire(self) -> dict[str, Any]:
        return {"at": [float(a) for a in self.at], "depth": self.depth, "radius": self.radius}


class ProbeReading(NamedTuple):
    """What a probe felt at the end of a step (NaN displacement and gap when ``outside``)."""

    force: float  # contact force >= 0 (the tissue is pushed along -axis, the tool along +axis)
    displacement: float  # the footprint-weighted displacement under the tip
    gap: float  # >= 0, 0 in contact
    in_contact: bool
    outside: bool  # the tip's centre is outside the domain: nothing touched


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """A live session's state after step ``k`` (time ``t``): the frame and the probes' readings."""

    k: int
    t: float
    z: np.ndarray | None  # shaped like the lattice; None when the step asked for no frame
    probes: tuple[ProbeReading, ...]
    info: SceneInfo | None = None

    def positions(self) -> np.ndarray:
        """(n, 3) world coordinates of every sphere (needs the frame and the description)."""
        if self.z is None or self.info is None:
            raise ProtocolError("this step carried no frame (step(..., frame=True) sends one)")
        return self.info.positions(self.z)

    @classmethod
    def from_reply(cls, reply: dict[str, Any], info: SceneInfo | None) -> LiveFrame:
        try:
            probes = tuple(ProbeReading(*(r[key] for key in _READING)) for r in reply["probes"])
            z = unpack_array(reply["z"]) if "z" in reply else None
            return cls(int(reply["k"]), float(reply["t"]), z, probes, info)
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"malformed live reply: {exc!r}") from None


_READING = ProbeReading._fields


class Session:
    """A live session on one scene (open it with ``Client.session``). Not thread-safe.

    Attributes:
        id: The session's id on the wire (random unless given, to join an open session).
        token: This object's own random token (sent on every live op; re-sends carry it).
        k: Steps taken so far (the index of the next step).
        residuals: How far the initial shapes were from what the modes carry (relative).
    """

    def __init__(self, client: Client, scene: str | None = None, session_id: str | None = None):
        self.client, self.scene = client, scene
        self.id = session_id or uuid.uuid4().hex
        self.token = secrets.token_hex(16)
        self.k = 0
        self.residuals: dict[str, float] = {}
        self.info: SceneInfo | None = None
        self.closed = False

    def open(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Session:
        """Start the session from rest, or from shapes on the lattice (sent as float32)."""
        shapes = {"displacement": displacement, "velocity": velocity}
        initial = {k: pack_array(np.asarray(v), "<f4") for k, v in shapes.items() if v is not None}
        reply = self._request(Op.OPEN, initial=initial or None)
        self.k, self.residuals = int(reply["k"]), dict(reply.get("residuals", {}))
        self.info = self.client.describe(self.scene)
        return self

    def step(self, loads: Any = (), probes: Any = (), *, frame: bool = True) -> LiveFrame:
        """Take step ``k`` under ``loads`` and ``probes`` (Load/Probe or their maps)."""
        wire_loads = [_wire(item) for item in loads]
        wire_probes = [_wire(item) for item in probes]
        reply = self._request(Op.STEP, k=self.k, loads=wire_loads, probes=wire_probes, frame=frame)
        result = LiveFrame.from_reply(reply, self.info)
        self.k = result.k
        return result

    def frame(self) -> LiveFrame:
        """The session's current frame (a display loop beside a haptic one)."""
        return LiveFrame.from_reply(self._request(Op.READ), self.info)

    def reset(self) -> None:
        """Back to the initial state, step 0."""
        self.k = int(self._request(Op.RESET)["k"])

    def close(self) -> None:
        """End the session on the server. Safe to call twice."""
        if not self.closed and not self.client.closed:
            self._request(Op.CLOSE)
        self.closed = True

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _request(self, op: str, **fields: Any) -> dict[str, Any]:
        return self.client.request(
            op, scene=self.scene, session=self.id, token=self.token, **fields
        )


def _wire(item: Any) -> Any:
    return item.to_wire() if isinstance(item, Load | Probe) else item
