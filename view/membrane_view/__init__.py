"""membrane_view: the scene in a browser (`membrane view`) and as an animation (`membrane animate`).

A membrane client on one side, a web page on the other: the bridge (``bridge``) serves a static
page and pushes frames over a WebSocket as binary float32 (``wire``). It imports the client and
the CLI helpers only (docs/VIEW.md).
"""

from membrane_view.wire import HEADER, HEADER_SIZE, MAGIC, decode_frame, encode_frame

__all__ = ["HEADER", "HEADER_SIZE", "MAGIC", "decode_frame", "encode_frame"]
