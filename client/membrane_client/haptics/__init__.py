"""Haptics: a force for a device every servo tick, rendered from what the server's steps send
(docs/HAPTICS.md).

- ``HapticLoop`` (``loop``): the servo thread in the user's process, the network side in a
  process of its own (``network``), sharing one small block of memory (``channel``);
- ``Coupling`` (``coupling``): the virtual coupling between the device and the tool proxy, and
  ``Contact``, a step's contact under the tip as the loop renders it.

numpy only: nothing here imports the server or the models.
"""

from membrane_client.haptics.coupling import Contact, Coupling, Proxy
from membrane_client.haptics.loop import HapticLoop, HapticReport, Tick

__all__ = ["Contact", "Coupling", "HapticLoop", "HapticReport", "Proxy", "Tick"]
