"""Several server workers behind one client: a session's every request goes to the worker that
owns it; film queries go to any of them.

One server process steps one session at a time, so `membrane serve --workers N` runs N worker
processes, each with its own sessions; on several machines, the same rule spans every worker's
endpoint. A live session's state lives in one worker, so its requests must always reach that
one: the owner is chosen by rendezvous (highest-random-weight) hashing of the session id over
the workers' endpoints, a rule that needs no shared table, gives every client (and the same
client after a restart) the same owner, and, when a worker leaves, moves only that worker's
sessions. No broker stands in front (a front endpoint would add a hop to every 1 kHz step and
be one more process to lose); the worker list comes from any worker's ``hello`` (``workers``).

A worker that stops answering is dropped from the list after the client's timeout: its
sessions then hash to another worker, which answers ``unknown_session`` (their state died with
their worker; ``reopen=True`` opens them anew there, from rest), and film queries go on through
the others, the query that timed out sent again to the next one.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import uuid
from collections.abc import Mapping, Sequence
from typing import Any

from membrane_client.client import Client
from membrane_client.errors import MembraneError, ServerError, Timeout
from membrane_client.frame import Frame, SceneInfo
from membrane_client.protocol import ErrorCode
from membrane_client.session import LiveFrame, Session

__all__ = ["NoWorkerLeft", "WorkerClient", "WorkerSession", "owner"]


class NoWorkerLeft(MembraneError):
    """Every worker stopped answering."""


def owner(session_id: str, endpoints: Sequence[str]) -> str:
    """The endpoint that owns ``session_id``: the highest hash of (endpoint, id)."""
    if not endpoints:
        raise NoWorkerLeft("no worker to own the session")

    def weight(endpoint: str) -> bytes:
        return hashlib.sha256(f"{endpoint}\0{session_id}".encode()).digest()

    return max(endpoints, key=weight)


class WorkerClient:
    """A client of several workers (``membrane serve --workers N``, or servers on several
    machines). Not thread-safe, as ``Client``.

    Args:
        endpoints: the workers' endpoints; or one, whose ``hello`` lists the others.
        timeout: seconds to wait for a reply before a worker counts as gone.
        options: ``Client``'s other keyword arguments (scene, socket_options, ...).
    """

    def __init__(
        self, endpoints: str | Sequence[str], *, timeout: float = 1.0, **options: Any
    ) -> None:
        listed = [endpoints] if isinstance(endpoints, str) else list(endpoints)
        if not listed:
            raise MembraneError("a WorkerClient needs at least one endpoint")
        self.timeout, self._options = timeout, options
        self.scene: str | None = options.get("scene")
        self._clients: dict[str, Client] = {}
        if len(listed) == 1:
            told = self.client(listed[0]).hello().workers
            listed = list(told) or listed
        self.endpoints: tuple[str, ...] = tuple(listed)  # as the workers name themselves
        self.alive: list[str] = list(listed)
        self._next = itertools.count()

    def client(self, endpoint: str) -> Client:
        """The one ``Client`` kept per worker."""
        if endpoint not in self._clients:
            self._clients[endpoint] = Client(endpoint, timeout=self.timeout, **self._options)
        return self._clients[endpoint]

    def owner_of(self, session_id: str) -> str:
        return owner(session_id, self.alive)

    def gone(self, endpoint: str) -> None:
        """A worker did not answer: drop it (its sessions now hash elsewhere)."""
        if endpoint in self.alive:
            self.alive.remove(endpoint)
        stale = self._clients.pop(endpoint, None)
        if stale is not None:
            stale.close()

    def query(self, t: float, scene: str | None = None, *, dtype: str = "<f4") -> Frame:
        """A film frame from the next worker in turn; a worker that times out is dropped and
        the query sent to the next."""
        while self.alive:
            endpoint = self.alive[next(self._next) % len(self.alive)]
            try:
                return self.client(endpoint).query(t, scene, dtype=dtype)
            except Timeout:
                self.gone(endpoint)
        raise NoWorkerLeft(f"none of the workers {', '.join(self.endpoints)} answers")

    def describe(self, scene: str | None = None) -> SceneInfo:
        while self.alive:
            endpoint = self.alive[0]
            try:
                return self.client(endpoint).describe(scene)
            except Timeout:
                self.gone(endpoint)
        raise NoWorkerLeft(f"none of the workers {', '.join(self.endpoints)} answers")

    def session(
        self,
        scene: str | None = None,
        initial: Mapping[str, Any] | None = None,
        *,
        session_id: str | None = None,
        reopen: bool = False,
    ) -> WorkerSession:
        """Open a live session on the worker its id hashes to (``WorkerSession``)."""
        return WorkerSession(self, scene or self.scene, session_id, reopen).open(initial)

    def close(self) -> None:
        for client in self._clients.values():
            client.close()
        self._clients.clear()

    def __enter__(self) -> WorkerClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class WorkerSession:
    """A live session on its owner worker: ``Session``'s ``step``, ``frame``, ``reset`` and
    ``close``, each sent to the worker the id hashes to now.

    When the owner stops answering, the request goes once more to the new owner, which answers
    ``unknown_session`` (a ``ServerError``): the state died with its worker. With ``reopen`` the
    session is opened there anew (from rest, or the shapes it was opened from), ``k`` back to
    0, and the step taken on it.
    """

    def __init__(
        self, workers: WorkerClient, scene: str | None, session_id: str | None, reopen: bool
    ) -> None:
        self.workers, self.scene, self.reopen = workers, scene, reopen
        self.id = session_id or uuid.uuid4().hex
        self.endpoint = workers.owner_of(self.id)
        self._session = Session(workers.client(self.endpoint), scene, self.id)
        self._initial: Mapping[str, Any] = {}
        self.reopened = 0  # times it was opened anew on another worker

    @property
    def k(self) -> int:
        return self._session.k

    def open(self, initial: Mapping[str, Any] | None = None) -> WorkerSession:
        self._initial = dict(initial or {})
        self._session.open(**self._initial)
        return self

    def step(self, *args: Any, **kwargs: Any) -> LiveFrame:
        return self._call(lambda s: s.step(*args, **kwargs))

    def frame(self, dtype: str = "<f4") -> LiveFrame:
        return self._call(lambda s: s.frame(dtype))

    def reset(self) -> None:
        self._call(lambda s: s.reset())

    def close(self) -> None:
        if self.workers.alive and self.workers.owner_of(self.id) == self.endpoint:
            with contextlib.suppress(Timeout, ServerError):  # gone, or forgot it: nothing left
                self._session.close()

    def _call(self, operation: Any) -> Any:
        self._follow_owner()
        try:
            return operation(self._session)
        except Timeout:  # StepLost too: the owner is gone
            self.workers.gone(self.endpoint)
            self._follow_owner()
        try:
            return operation(self._session)
        except ServerError as exc:
            if exc.code != ErrorCode.UNKNOWN_SESSION or not self.reopen:
                raise
        self._session.open(**self._initial)
        self.reopened += 1
        return operation(self._session)

    def _follow_owner(self) -> None:
        """Point the session at the worker its id hashes to now (same id, token and k)."""
        now = self.workers.owner_of(self.id)
        if now != self.endpoint:
            self.endpoint = now
            self._session.client = self.workers.client(now)

    def __enter__(self) -> WorkerSession:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
