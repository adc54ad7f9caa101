"""membrane_client: the thin client (pyzmq, msgpack, numpy only).

```python
from membrane_client import Client

with Client("tcp://127.0.0.1:5555", timeout=1.0) as client:
    info = client.describe()
    frame = client.query(0.5)
    positions = frame.positions()  # (n, 3) world coordinates of every sphere

    with client.session("membrane-live") as session:  # a live scene: press on it
        frame = session.step(probes=[Probe((0.5, 0.5), depth=0.001, radius=0.05)])
        force = frame.probes[0].force
```
"""

from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_client.errors import (
    MembraneError,
    ProtocolError,
    ServerError,
    StepLost,
    Timeout,
    UserError,
)
from membrane_client.frame import Frame, SceneInfo
from membrane_client.live_limits import InvalidInput, LiveLimits
from membrane_client.live_schema import (
    Grasp,
    GraspReading,
    Load,
    Probe,
    ProbeReading,
    Tool,
    ToolReading,
)
from membrane_client.protocol import PROTOCOL_VERSION, ErrorCode
from membrane_client.session import LiveFrame, Session

__all__ = [
    "DEFAULT_ADDRESS",
    "PROTOCOL_VERSION",
    "Client",
    "ErrorCode",
    "Frame",
    "Grasp",
    "GraspReading",
    "InvalidInput",
    "LiveFrame",
    "LiveLimits",
    "Load",
    "MembraneError",
    "Probe",
    "ProbeReading",
    "ProtocolError",
    "SceneInfo",
    "ServerError",
    "Session",
    "StepLost",
    "Timeout",
    "Tool",
    "ToolReading",
    "UserError",
]
