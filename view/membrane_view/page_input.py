"""What the page sends, checked before it reaches the pointer (and so the server).

The page is served by the bridge, but whatever holds the token can send anything on its
WebSocket, and a bad probe passed on would cost a server round trip or the session. So each
text message is bounded in size and nesting before it is parsed (``json.loads`` recurses, and
a deep array raised RecursionError out of the receive loop), and a press goes through the
client's ``LiveLimits`` with the scene's own bounds, its depth within the slider's range.
A press is a probe's wire map (``live_schema.Probe``) plus its ``type`` and, optionally, the
``tool`` that presses (``PAGE_TOOLS``: a soft tip, the probe, by default; a rigid sphere or
cylinder; a grasp, which holds the tissue ``depth`` above rest): its place, depth and radius are
checked as a probe's, and the tool must be one the scene takes. A refused message is answered
with one short error and changes nothing.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from membrane_client.live_limits import LiveLimits
from membrane_client.live_schema import PROBE_KEYS, Probe
from membrane_client.protocol import preview
from membrane_errors import UserError

__all__ = [
    "MAX_ERROR_CHARS",
    "MAX_MESSAGE_CHARS",
    "MAX_NESTING",
    "PAGE_TOOLS",
    "PageInputError",
    "PageMessage",
    "error_message",
    "nesting_exceeds",
    "parse_page_message",
]

MAX_MESSAGE_CHARS = 4096  # the page's messages are under 200 characters
MAX_NESTING = 4  # the page's deepest is 2 (a press's coordinates)
MAX_ERROR_CHARS = 300
_PROBE_KEYS = frozenset(PROBE_KEYS)
_PROBE_NAMES = f"{', '.join(PROBE_KEYS[:-1])} and {PROBE_KEYS[-1]}"
_KINDS = ("press", "release", "reset")
# What presses: the probe (a soft tip), the two rigid tools, a grasp (held at +depth).
PAGE_TOOLS = ("tip", "sphere", "cylinder", "grasp")


class PageInputError(UserError):
    """A message from the page that the bridge refuses (it is answered, the socket kept)."""


@dataclass(frozen=True)
class PageMessage:
    """A checked message: ``kind`` is press, release or reset; a press carries its probe (the
    place, depth and radius of whichever ``tool`` presses)."""

    kind: str
    probe: Probe | None = None
    tool: str = "tip"


def parse_page_message(
    text: str,
    limits: LiveLimits | None,
    max_depth: float,
    no_press: str = "press needs a live scene (this one plays a film)",
    tools: tuple[str, ...] = ("tip",),
) -> PageMessage:
    """Check one text message from the page.

    Args:
        text: the WebSocket message.
        limits: the live scene's bounds; None when a press cannot be taken now.
        max_depth: the slider's maximum depth; a press deeper than it (or than the scene's own
            bound, whichever is tighter) is refused.
        no_press: why, when ``limits`` is None (a film, or no scene described yet).
        tools: the ``PAGE_TOOLS`` the scene takes.

    Raises:
        PageInputError: what is wrong, in one line quoting at most 64 characters of any value.
    """
    if len(text) > MAX_MESSAGE_CHARS:
        reason = f"a message is at most {MAX_MESSAGE_CHARS} characters, got {len(text)}"
        raise PageInputError(reason)
    if nesting_exceeds(text, MAX_NESTING):
        raise PageInputError(f"a message nests at most {MAX_NESTING} levels deep")
    try:
        message: Any = json.loads(text)
    except RecursionError:  # not reached after the nesting check; kept so it can never escape
        raise PageInputError("a message nests too deep") from None
    except ValueError as exc:
        raise PageInputError(f"not JSON ({type(exc).__name__})") from None
    if type(message) is not dict:
        raise PageInputError(f"a message is a JSON object, got {_kind(message)}")
    kind = message.get("type")
    if kind not in _KINDS:
        raise PageInputError(f"unknown type {_kind(kind)}: the page sends {', '.join(_KINDS)}")
    if kind != "press":
        if len(message) > 1:
            raise PageInputError(f"{kind} takes no fields besides type ({len(message) - 1} sent)")
        return PageMessage(kind)
    fields = {key: value for key, value in message.items() if key not in ("type", "tool")}
    tool = message.get("tool", "tip")
    if tool not in tools:
        raise PageInputError(f"tool {_kind(tool)}: this scene takes {', '.join(tools)}")
    if fields.keys() != _PROBE_KEYS:
        missing = sorted(_PROBE_KEYS - fields.keys())
        extra = len(fields.keys() - _PROBE_KEYS)
        raise PageInputError(
            f"press takes exactly {_PROBE_NAMES}, and a tool or not (missing {missing}, "
            f"{extra} other)"
        )
    if limits is None:
        raise PageInputError(no_press)
    try:
        probe = limits.probe_from_wire(fields, max_depth=max_depth, min_depth=0.0)  # presses only
    except UserError as exc:
        raise PageInputError(str(exc)) from None
    if tool in ("sphere", "cylinder") and not probe.radius > 0.0:
        raise PageInputError(f"a {tool}'s radius must be > 0, got {probe.radius:.6g}")
    return PageMessage("press", probe, tool)


def nesting_exceeds(text: str, limit: int) -> bool:
    """Whether JSON text nests arrays and objects more than ``limit`` deep (one pass over the
    characters, strings skipped: no recursion, linear in the length)."""
    if text.count("[") + text.count("{") <= limit:
        return False
    depth = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > limit:
                return True
        elif char in "]}":
            depth -= 1
    return False


def error_message(text: str, source: str = "bridge") -> dict[str, Any]:
    """An ``error`` message for the page: one line of at most ``MAX_ERROR_CHARS`` characters.
    ``source`` is "page" when the page's own message was refused (nothing else changed)."""
    line = " ".join(text.split())
    if len(line) > MAX_ERROR_CHARS:
        line = line[: MAX_ERROR_CHARS - 3] + "..."
    return {"type": "error", "source": source, "message": line}


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool | int | float | str):
        return preview(value)
    return preview(value) if isinstance(value, dict | list) else type(value).__name__
