"""Who may talk to the bridge: only a page it served itself, from its own address.

Any web page the user visits can make the browser send requests to 127.0.0.1, so a loopback
address is no protection on its own. Three checks, in an aiohttp middleware:

- ``Host`` must be the bridge's own address (127.0.0.1, localhost or the address the request
  arrived on, with the bridge's port): a DNS-rebound name (evil.example resolving to 127.0.0.1)
  is refused, so a foreign page never reads the bridge's responses through its own origin.
- ``Origin``, when the browser sends one (always on a WebSocket), must be ``http://`` plus one
  of those addresses: a page from another origin cannot open the WebSocket.
- The page and the WebSocket need the token printed at start (``?token=``, as Jupyter does);
  compared in constant time. The page's own modules and style (``/static/``) need no token:
  they hold nothing secret.

Every refusal is a 403 with one line of text; nothing of the request is echoed.
"""

from __future__ import annotations

import hmac
import secrets
from collections.abc import Awaitable, Callable

from aiohttp import web
from aiohttp.typedefs import Middleware

__all__ = [
    "TOKEN_PATHS",
    "guard",
    "new_token",
    "own_hosts",
    "security_headers",
    "token_matches",
]

TOKEN_PATHS = frozenset({"/", "/ws"})
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
# The page fetches only its own files and its WebSocket, and is never framed.
CONTENT_POLICY = (
    "default-src 'self'; connect-src 'self'; img-src 'self' data:; object-src 'none'; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def new_token() -> str:
    """A fresh token (43 URL-safe characters, 256 bits)."""
    return secrets.token_urlsafe(32)


def own_hosts(sockname: object) -> frozenset[str]:
    """The ``Host`` values that name this bridge, from the socket a request arrived on."""
    if not isinstance(sockname, tuple) or len(sockname) < 2:
        return frozenset()
    address, port = str(sockname[0]), int(sockname[1])
    local = f"[{address}]" if ":" in address else address
    names = {*LOOPBACK_NAMES, local.lower()}
    hosts = {f"{name}:{port}" for name in names}
    return frozenset(hosts | names if port == 80 else hosts)


def token_matches(given: str | None, token: str) -> bool:
    """Constant-time comparison (the time taken says nothing of how much matched)."""
    if given is None:
        return False
    return hmac.compare_digest(given.encode("utf-8", "replace"), token.encode("utf-8"))


def guard(token: str) -> Middleware:
    """The middleware: Host, Origin and (on the page and the WebSocket) the token."""

    @web.middleware
    async def check(request: web.Request, handler: Handler) -> web.StreamResponse:
        transport = request.transport
        hosts = own_hosts(transport.get_extra_info("sockname") if transport else None)
        named = request.headers.getall("Host", [])
        if len(named) != 1 or named[0].lower() not in hosts:
            return _forbidden("Host is not this bridge's address (DNS rebinding is refused)")
        origins = request.headers.getall("Origin", [])
        if origins and (len(origins) != 1 or origins[0].lower() not in _origins(hosts)):
            return _forbidden("Origin is not this bridge's page: only its own page may connect")
        if request.path in TOKEN_PATHS and not token_matches(request.query.get("token"), token):
            return _forbidden(
                "a token is needed: open the address `membrane view` printed at start "
                "(it ends in ?token=...)"
            )
        return await handler(request)

    return check


async def security_headers(request: web.Request, response: web.StreamResponse) -> None:
    """On every response (an ``on_response_prepare`` signal): no framing, no referrer (the
    page's address holds the token), no caching of the page, nothing from elsewhere."""
    response.headers["Content-Security-Policy"] = CONTENT_POLICY
    response.headers["Referrer-Policy"] = "no-referrer"
    response.headers["X-Content-Type-Options"] = "nosniff"
    response.headers["X-Frame-Options"] = "DENY"
    if request.path == "/":
        response.headers["Cache-Control"] = "no-store"


def _origins(hosts: frozenset[str]) -> frozenset[str]:
    return frozenset(f"http://{host}" for host in hosts)


def _forbidden(reason: str) -> web.Response:
    return web.Response(status=403, text=f"403 Forbidden: {reason}\n")
