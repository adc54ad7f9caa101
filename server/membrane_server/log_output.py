"""Log output that can neither flood the log nor stall the serving thread.

The server logs from its serving thread (an internal error, a refused reload). A handler that
writes there blocks that thread as soon as its output does: a stderr pipe nobody reads fills at
64 KiB, and every client waits. And a request that makes the server log a traceback, sent in a
loop, writes megabytes a second. So ``LogOutput``:

- never writes in the caller's thread: a formatted line goes into a bounded queue (lines and
  bytes) that a writer thread drains with ``os.write`` (no Python-level lock is held while the
  output blocks); a line that finds the queue full is dropped and counted, and once the output
  moves again one line says how many were dropped;
- lets through at most ``per_kind`` lines per window (a second) of one kind (logger, level and
  message template: never the arguments, which a client may choose) and ``overall`` lines of
  all kinds; the rest are counted, and one line per kind and window says how many were
  suppressed;
- writes a traceback in full once per kind (exception type and the line that raised it), then
  one line naming it.

``log_counts()`` sums the counters of the installed outputs, for ``stats``.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, Any

__all__ = ["LOG_FORMAT", "LogOutput", "descriptor", "install", "installed", "log_counts"]

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"

# Lines of one kind let through per window, and of all kinds together.
DEFAULT_PER_KIND = 10
DEFAULT_OVERALL = 100
DEFAULT_WINDOW_S = 1.0
# What may wait for the output: past either bound, lines are dropped and counted.
DEFAULT_MAX_QUEUED_LINES = 1000
DEFAULT_MAX_QUEUED_BYTES = 1024 * 1024
# One record's text at most (a traceback included); the rest is cut, and the line says so.
MAX_LINE_BYTES = 16 * 1024
# Kinds remembered for rate limiting and for tracebacks (the least recently seen are forgotten).
MAX_KINDS = 1024
# How long the writer waits when a non-blocking output refuses bytes.
_RETRY_S = 0.01
_PREVIEW_CHARS = 160
_COUNTS = ("written", "dropped", "suppressed", "tracebacks_shortened", "failed")

_outputs: list[LogOutput] = []
_outputs_lock = threading.Lock()


class _Window:
    """One kind's lines in its current window."""

    __slots__ = ("logger", "passed", "started", "suppressed", "template")

    def __init__(self, started: float, logger: str, template: str) -> None:
        self.started, self.logger, self.template = started, logger, template
        self.passed = 0
        self.suppressed = 0


class LogOutput(logging.Handler):
    """A logging handler that queues lines for a writer thread; see the module's docstring.

    Args:
        stream: Where lines go: a file object with a descriptor (``sys.stderr``, a log file)
            or a descriptor. It is written with ``os.write``, never through the object.
        per_kind: Lines of one kind written per window.
        overall: Lines of all kinds written per window.
        window_s: The window, in seconds.
        max_queued_lines, max_queued_bytes: What may wait for the output.
        clock: Monotonic seconds (tests pass their own).
    """

    def __init__(
        self,
        stream: IO[str] | int,
        *,
        per_kind: int = DEFAULT_PER_KIND,
        overall: int = DEFAULT_OVERALL,
        window_s: float = DEFAULT_WINDOW_S,
        max_queued_lines: int = DEFAULT_MAX_QUEUED_LINES,
        max_queued_bytes: int = DEFAULT_MAX_QUEUED_BYTES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if per_kind < 1 or overall < 1 or not window_s > 0:
            raise ValueError("per_kind and overall must be >= 1, and window_s > 0")
        self._fd = descriptor(stream)  # raises before logging knows of this handler
        super().__init__()
        self.per_kind, self.overall, self.window_s = per_kind, overall, window_s
        self.max_queued_lines, self.max_queued_bytes = max_queued_lines, max_queued_bytes
        self._clock = clock
        # Guards the queue, the windows and the counters; never held while writing.
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._queue: collections.deque[bytes] = collections.deque()
        self._queued_bytes = 0
        self._writing = False
        self._windows: collections.OrderedDict[tuple[Any, ...], _Window] = collections.OrderedDict()
        # Kinds forgotten (past MAX_KINDS) before their suppressions were told: how many, lines.
        self._evicted_kinds = 0
        self._evicted_lines = 0
        self._next_summary_at = clock() + window_s
        self._overall_started = -float("inf")
        self._overall_passed = 0
        self._tracebacks: collections.OrderedDict[tuple[str, ...], tuple[str, int]] = (
            collections.OrderedDict()
        )
        self._dropped_untold = 0
        self.counts: collections.Counter[str] = collections.Counter()
        self._closed = False
        self._writer = threading.Thread(target=self._write_forever, name="membrane-log")
        self._writer.daemon = True  # it may be blocked on an output nobody reads: never waited for
        self._writer.start()

    # -- the caller's side: never blocks on the output ----------------------------------------

    def handle(self, record: logging.LogRecord) -> bool:
        """Filter, rate-limit, format and queue ``record``; never raises, never writes."""
        try:
            if not self.filter(record):
                return False
            self.emit(record)
        except Exception:  # a broken record or formatter costs that line, never the caller
            self._count("failed")
        return True

    def emit(self, record: logging.LogRecord) -> None:
        """Queue the record's line, unless its kind or the whole output is over its rate."""
        with self._lock:
            admitted = self._admit(_kind(record), record, self._clock())
        if admitted:
            self._enqueue(self._line(record))

    def write_text(self, text: str) -> None:
        """Queue ``text`` as it is (no format, no rate limit): a program's own last line."""
        self._enqueue(text.encode("utf-8", "backslashreplace"))

    def flush(self) -> None:
        """Give the queued lines half a second to be written (what logging does at exit)."""
        self.drain(0.5)

    def drain(self, timeout: float = 1.0) -> bool:
        """Wait up to ``timeout`` seconds for the queued lines to be written; True if they were."""
        deadline = time.monotonic() + timeout
        with self._wake:
            while self._queue or self._writing:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._wake.wait(min(left, 0.05))
        return True

    def close(self) -> None:
        """Take no more lines (those queued are still written while the process lives)."""
        self._closed = True
        with _outputs_lock:
            if self in _outputs:
                _outputs.remove(self)
        super().close()

    def handleError(self, record: logging.LogRecord) -> None:
        """Count the failure: logging's default prints to stderr, which may block."""
        self._count("failed")

    def snapshot(self) -> dict[str, int]:
        """The counters: lines written, dropped (the output did not keep up), suppressed (over
        the rate), tracebacks shortened to one line, failed (a record that could not be
        formatted), and the lines queued now."""
        with self._lock:
            counts = {name: self.counts[name] for name in _COUNTS}
            counts["queued"] = len(self._queue)
        return counts

    # -- internals ----------------------------------------------------------------------------

    def _admit(self, key: tuple[Any, ...], record: logging.LogRecord, now: float) -> bool:
        """Whether the record is written; counts it either way (under the lock)."""
        window = self._windows.get(key)
        if window is None:
            window = _Window(now, record.name, _template(record))
            self._windows[key] = window
            while len(self._windows) > MAX_KINDS:
                _, forgotten = self._windows.popitem(last=False)
                if forgotten.suppressed:
                    self._evicted_kinds += 1
                    self._evicted_lines += forgotten.suppressed
        else:
            self._windows.move_to_end(key)
            if now - window.started >= self.window_s and not window.suppressed:
                window.started, window.passed = now, 0  # else the writer tells, then resets
        if now - self._overall_started >= self.window_s:
            self._overall_started, self._overall_passed = now, 0
        if window.passed < self.per_kind and self._overall_passed < self.overall:
            window.passed += 1
            self._overall_passed += 1
            return True
        window.suppressed += 1
        self.counts["suppressed"] += 1
        return False

    def _line(self, record: logging.LogRecord) -> bytes:
        """The record formatted, its traceback in full only the first time of its kind."""
        if record.exc_info and record.exc_info[1] is not None:
            record = self._shorten_known_traceback(record, record.exc_info[1])
        data = self.format(record).encode("utf-8", "backslashreplace")
        if len(data) > MAX_LINE_BYTES:
            cut = len(data) - MAX_LINE_BYTES
            data = data[:MAX_LINE_BYTES] + f" ... [{cut} bytes cut]".encode()
        return data

    def _shorten_known_traceback(
        self, record: logging.LogRecord, exc: BaseException
    ) -> logging.LogRecord:
        kind = _traceback_kind(exc)
        with self._lock:
            known = self._tracebacks.get(kind)
            if known is None:
                self._tracebacks[kind] = (time.strftime("%H:%M:%S"), 1)
                while len(self._tracebacks) > MAX_KINDS:
                    self._tracebacks.popitem(last=False)
                return record
            first_at, seen = known[0], known[1] + 1
            self._tracebacks[kind] = (first_at, seen)
            self._tracebacks.move_to_end(kind)
            self.counts["tracebacks_shortened"] += 1
        short = logging.makeLogRecord(record.__dict__)
        short.msg = (
            f"{record.getMessage()} [{type(exc).__name__}: {_preview(str(exc))}; its traceback "
            f"as written at {first_at}; seen {seen} times]"
        )
        short.args, short.exc_info, short.exc_text, short.stack_info = None, None, None, None
        return short

    def _enqueue(self, data: bytes) -> None:
        if self._closed:
            return
        with self._wake:
            if (
                len(self._queue) >= self.max_queued_lines
                or self._queued_bytes + len(data) > self.max_queued_bytes
            ):
                self.counts["dropped"] += 1
                self._dropped_untold += 1
                return
            self._queue.append(data)
            self._queued_bytes += len(data)
            self._wake.notify()

    def _count(self, name: str) -> None:
        with self._lock:
            self.counts[name] += 1

    def _write_forever(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._summaries_due(self._clock()):
                    self._wake.wait(self.window_s / 4)
                lines = list(self._queue)
                self._queue.clear()
                self._queued_bytes = 0
                summaries = self._take_summaries(self._clock())
                dropped, self._dropped_untold = self._dropped_untold, 0
                self._writing = True
            chunks = lines + [self._notice(logger, text) for logger, text in summaries]
            if dropped:  # told once the output moves again
                chunks.append(self._notice(__name__, f"{dropped} log lines dropped: the log "
                                           "output did not keep up"))  # fmt: skip
            written = 0
            try:
                written = self._write_lines(chunks)
            finally:
                with self._wake:
                    self._writing = False
                    self.counts["written"] += written
                    self.counts["dropped"] += len(chunks) - written
                    self._wake.notify_all()

    def _write_lines(self, lines: list[bytes]) -> int:
        """Write whole lines; returns how many were written (the rest go with a lost output)."""
        for index, line in enumerate(lines):
            data = memoryview(line + b"\n")
            while data:
                try:
                    data = data[os.write(self._fd, data) :]
                except (BlockingIOError, InterruptedError):
                    time.sleep(_RETRY_S)
                except OSError:  # the output is gone (EPIPE, EBADF): nowhere to write
                    return index
        return len(lines)

    def _summaries_due(self, now: float) -> bool:
        """Suppressions are told once per window, all kinds together."""
        if now < self._next_summary_at:
            return False
        return bool(self._evicted_kinds) or any(w.suppressed for w in self._windows.values())

    def _take_summaries(self, now: float) -> list[tuple[str, str]]:
        """The lines telling how many were suppressed, per kind whose window is over (and
        reset those windows)."""
        if not self._summaries_due(now):
            return []
        self._next_summary_at = now + self.window_s
        due = [window for window in self._windows.values() if window.suppressed]
        windows = sorted(due, key=lambda w: -w.suppressed)
        told = [
            (window.logger, (
                f"{_lines(window.suppressed)} like {_preview(window.template)!r} suppressed in "
                f"{now - window.started:.1f} s (at most {self.per_kind} lines of a kind and "
                f"{self.overall} in all are written per {self.window_s:g} s)"
            ))
            for window in windows[: self.per_kind]
        ]  # fmt: skip
        rest = windows[self.per_kind :]
        kinds = len(rest) + self._evicted_kinds
        if kinds:  # many kinds at once: the summaries themselves must not flood
            lines = sum(window.suppressed for window in rest) + self._evicted_lines
            told.append(
                (
                    __name__,
                    f"{_lines(lines)} of {kinds} other kinds suppressed (at most "
                    f"{self.overall} lines are written per {self.window_s:g} s)",
                )
            )
        for window in windows:
            window.started, window.passed, window.suppressed = now, 0, 0
        self._evicted_kinds = self._evicted_lines = 0
        return told

    def _notice(self, logger: str, text: str) -> bytes:
        record = logging.makeLogRecord(
            {"name": logger, "levelno": logging.WARNING, "levelname": "WARNING", "msg": text}
        )
        return self.format(record).encode("utf-8", "backslashreplace")


def _kind(record: logging.LogRecord) -> tuple[Any, ...]:
    """What makes two records the same kind: never the arguments, which a client may choose."""
    return (record.name, record.levelno, _template(record), record.exc_info is not None)


def _template(record: logging.LogRecord) -> str:
    msg = record.msg
    return msg if isinstance(msg, str) else type(msg).__name__


def _traceback_kind(exc: BaseException) -> tuple[str, ...]:
    """The exception's type and the innermost line of its traceback."""
    tb, where = exc.__traceback__, ""
    while tb is not None:
        where = f"{tb.tb_frame.f_code.co_filename}:{tb.tb_lineno}"
        tb = tb.tb_next
    return (type(exc).__module__, type(exc).__qualname__, where)


def _lines(count: int) -> str:
    return f"{count} more line" if count == 1 else f"{count} more lines"


def _preview(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= _PREVIEW_CHARS else text[:_PREVIEW_CHARS] + "..."


def descriptor(stream: IO[str] | int) -> int:
    """The descriptor a stream writes to (what was written through the object is flushed);
    raises OSError (io.UnsupportedOperation) when it has none, as a captured stream."""
    if isinstance(stream, int):
        return stream
    with contextlib.suppress(Exception):
        stream.flush()
    return stream.fileno()


def install(stream: IO[str] | int, *, replace_all: bool = False) -> LogOutput | None:
    """Make a ``LogOutput`` on ``stream`` the root logger's handler for that output, keeping
    the format of the handler it replaces (else ``LOG_FORMAT``); returns it, or None (and
    nothing changed) when ``stream`` has no descriptor. It replaces the root's handlers that
    write to the same descriptor or to stderr (``replace_all``: every handler). Warnings go
    through it too (``warnings.showwarning`` would write to stderr itself)."""
    try:
        fd = descriptor(stream)
    except (OSError, ValueError):
        return None
    root = logging.getLogger()
    formatter: logging.Formatter | None = None
    for handler in list(root.handlers):
        if replace_all or isinstance(handler, LogOutput) or _writes_to(handler, fd):
            formatter = formatter or handler.formatter
            root.removeHandler(handler)
            handler.close()
    output = LogOutput(fd)
    output.setFormatter(formatter or logging.Formatter(LOG_FORMAT))
    root.addHandler(output)
    logging.captureWarnings(True)
    with _outputs_lock:
        _outputs.append(output)
    return output


def _writes_to(handler: logging.Handler, fd: int) -> bool:
    stream = getattr(handler, "stream", None)
    if stream is None:
        return False
    if stream is sys.stderr or stream is sys.__stderr__:
        return True
    try:
        return bool(stream.fileno() == fd)
    except (OSError, ValueError, AttributeError):
        return False


def installed() -> LogOutput | None:
    """The root logger's ``LogOutput``, if one is installed."""
    return next((h for h in logging.getLogger().handlers if isinstance(h, LogOutput)), None)


def log_counts() -> dict[str, int]:
    """The installed outputs' counters summed (zeros when none is installed)."""
    with _outputs_lock:
        outputs = list(_outputs)
    total = dict.fromkeys((*_COUNTS, "queued"), 0)
    for output in outputs:
        for name, value in output.snapshot().items():
            total[name] += value
    return total
