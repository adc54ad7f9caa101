"""membrane_client: the thin client (pyzmq, msgpack, numpy only).

```python
from membrane_client import Client

with Client("tcp://127.0.0.1:5555", timeout=1.0) as client:
    info = client.describe()
    frame = client.query(0.5)
    positions = frame.positions()  # (n, 3) world coordinates of every sphere
```
"""

from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_client.errors import MembraneError, ProtocolError, ServerError, Timeout, UserError
from membrane_client.frame import Frame, SceneInfo
from membrane_client.protocol import PROTOCOL_VERSION, ErrorCode

__all__ = [
    "DEFAULT_ADDRESS",
    "PROTOCOL_VERSION",
    "Client",
    "ErrorCode",
    "Frame",
    "MembraneError",
    "ProtocolError",
    "SceneInfo",
    "ServerError",
    "Timeout",
    "UserError",
]
