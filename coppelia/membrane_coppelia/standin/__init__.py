"""A stand-in for CoppeliaSim 4.6-4.9 and its ZeroMQ remote API add-on: a test double that the
real ``coppeliasim-zmqremoteapi-client`` talks to unmodified, for the tests, the benchmark and
trying the adapter without CoppeliaSim (``python -m membrane_coppelia.standin --port 23000``).

- ``addon``: the add-on's protocol (CBOR requests to replies, clients and their stepping
  levels) and its pass loop on a REP socket (:class:`CoppeliaStandin`);
- ``scene``: the scene behind it, playing one release's ``sim.*`` calls (:class:`FakeScene`);
- ``__main__``: the command.

It is not part of the adapter: nothing outside this package imports it.
"""

from membrane_coppelia.standin.addon import (
    DEFAULT_CLIENT_TIMEOUT,
    PROTOCOL_VERSION,
    CoppeliaStandin,
    RemoteApiProtocol,
    RemoteClient,
)
from membrane_coppelia.standin.scene import (
    RELEASES,
    SIM_CONSTANTS,
    CallRefused,
    FakeObject,
    FakeScene,
    Release,
)

__all__ = [
    "DEFAULT_CLIENT_TIMEOUT",
    "PROTOCOL_VERSION",
    "RELEASES",
    "SIM_CONSTANTS",
    "CallRefused",
    "CoppeliaStandin",
    "FakeObject",
    "FakeScene",
    "Release",
    "RemoteApiProtocol",
    "RemoteClient",
]
