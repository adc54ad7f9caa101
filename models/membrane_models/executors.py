"""Where batch jobs run: one after another in this process, or as tasks on Ray.

Sweeps of trainings are embarrassingly parallel, and a machine's cores (or a cluster's machines)
can take one job each. Rather than a home-made pool, the parallel executor is Ray's (the
``cluster`` extra): a local Ray started for the run by default, or an existing cluster at
``--ray-address``. A job is a module-level function and picklable arguments, so the same job
runs the same way in either executor, and results come back in the jobs' order; each job seeds
and pins its own threads (a training: ``torch.set_num_threads(1)``), so a seeded job's result
does not depend on where it ran.

Ray is imported only when a Ray executor runs: neither the server nor the client install it
(import-linter contracts ``server`` and ``client``).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from membrane_errors import UserError

__all__ = [
    "EXECUTORS",
    "Executor",
    "Job",
    "RayExecutor",
    "RayFutures",
    "SerialExecutor",
    "add_executor_arguments",
    "executor_from_args",
]

R = TypeVar("R")
EXECUTORS = ("serial", "ray")


@dataclass(frozen=True)
class Job(Generic[R]):
    """One unit of a batch: ``fn(*args)``, named in progress and errors."""

    name: str
    fn: Callable[..., R]
    args: tuple[Any, ...] = ()


# what a finished job's progress line says of its result (``Executor.run``'s ``report``)
Report = Callable[[Any], str]


class Executor(Protocol):
    """Runs jobs and returns their results in the jobs' order; with ``progress``, a line as
    each starts (serial) or ends, with ``report(result)`` once it has ended where given."""

    name: str

    def run(
        self, jobs: Sequence[Job[R]], progress: bool = True, report: Report | None = None
    ) -> list[R]: ...


class SerialExecutor:
    """Each job in this process, one after another (the reference for the parallel ones)."""

    name = "serial"

    def run(
        self, jobs: Sequence[Job[R]], progress: bool = True, report: Report | None = None
    ) -> list[R]:
        results = []
        for index, job in enumerate(jobs):
            if progress:
                print(f"[{index + 1}/{len(jobs)}] {job.name} ...", flush=True)
            results.append(job.fn(*job.args))
            if progress and report is not None:
                print(f"[{index + 1}/{len(jobs)}] {job.name}: {report(results[-1])}", flush=True)
        return results


class RayExecutor:
    """Each job a Ray task of one CPU: on a local Ray of ``workers`` CPUs started for the run
    (and stopped after it), or on the cluster at ``address``."""

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None) -> None:
        if workers is not None and workers < 1:
            raise UserError(f"--workers must be >= 1, got {workers}")
        self.address, self.workers = address, workers

    def run(
        self, jobs: Sequence[Job[R]], progress: bool = True, report: Report | None = None
    ) -> list[R]:
        ray = _import_ray(local=self.address is None)
        started = time.perf_counter()
        owned = not ray.is_initialized()
        if owned:
            _start(ray, self.address, self.workers)
        try:
            if progress:
                cpus = ray.cluster_resources().get("CPU", 0)
                where = self.address or f"a local Ray of {cpus:g} CPUs"
                took = time.perf_counter() - started
                print(f"ray: {len(jobs)} jobs on {where} ({took:.1f} s to start)", flush=True)
            task = ray.remote(num_cpus=1, max_retries=0)(_call)
            refs = [task.remote(job.fn, job.args) for job in jobs]
            try:
                _wait_all(ray, refs, jobs, progress, report)
                return list(ray.get(refs))
            except ray.exceptions.RayTaskError as exc:
                if isinstance(exc.cause, UserError):  # a job's one-line refusal, as serially
                    raise exc.cause from None
                raise
        finally:
            if owned:
                ray.shutdown()

    @contextmanager
    def futures(self) -> Iterator[RayFutures]:
        """Ray tasks behind ``concurrent.futures.Executor`` (``submit``, ``map``), for code
        written against a process pool (``membrane data``'s); Ray started and stopped around."""
        ray = _import_ray(local=self.address is None)
        owned = not ray.is_initialized()
        if owned:
            _start(ray, self.address, self.workers)
        try:
            yield RayFutures(ray)
        finally:
            if owned:
                ray.shutdown()


class RayFutures(concurrent.futures.Executor):
    """``submit`` as a Ray task of one CPU; its future is the task's (``ObjectRef.future``)."""

    def __init__(self, ray: Any) -> None:
        self._task = ray.remote(num_cpus=1, max_retries=0)(_call)

    def submit(
        self, fn: Callable[..., R], /, *args: Any, **kwargs: Any
    ) -> concurrent.futures.Future[R]:
        if kwargs:
            raise TypeError("RayFutures.submit takes positional arguments only")
        future: concurrent.futures.Future[R] = self._task.remote(fn, args).future()
        return future


def _call(fn: Callable[..., R], args: tuple[Any, ...]) -> R:
    return fn(*args)


# Ray's local node otherwise takes this machine's network address and listens on every
# interface; with this set (Ray's own switch, read when it is imported) a local Ray's services
# bind to 127.0.0.1 only.
_LOOPBACK_ONLY = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _import_ray(local: bool) -> Any:
    if local:
        os.environ[_LOOPBACK_ONLY] = "0"
    try:
        import ray
    except ImportError:
        raise UserError(
            "--executor ray needs Ray: pip install 'membrane-tissue[cluster]'"
        ) from None
    if local:  # Ray imported before this run read its switch then: set it where it is kept
        from ray._private import ray_constants

        ray_constants.ENABLE_RAY_CLUSTER = False
    return ray


def _start(ray: Any, address: str | None, workers: int | None) -> None:
    """Join the cluster at ``address``, or start a local one (no dashboard, quiet, bound to
    127.0.0.1)."""
    options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
    try:
        if address is not None:
            ray.init(address=address, **options)
        else:  # this machine's, on the loopback interface (``_import_ray``)
            ray.init(num_cpus=workers, **options)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = address or "a local Ray"
        raise UserError(f"could not start or join {where}: {exc}") from None


def _wait_all(
    ray: Any, refs: list[Any], jobs: Sequence[Job[Any]], progress: bool, report: Report | None
) -> None:
    """Wait for every task, saying each one's end (and ``report`` of its result) as it comes."""
    names = {ref: job.name for ref, job in zip(refs, jobs, strict=True)}
    pending, done = list(refs), 0
    while pending:
        finished, pending = ray.wait(pending, num_returns=1)
        done += len(finished)
        if progress:
            for ref in finished:
                said = "done" if report is None else report(ray.get(ref))
                print(f"[{done}/{len(refs)}] {names[ref]}: {said}", flush=True)


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor``, ``--ray-address`` and ``--workers`` on a batch command."""
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        help="where the jobs run: one after another here (serial, default) or as Ray tasks "
        "(ray: a local Ray unless --ray-address; needs membrane-tissue[cluster])",
    )
    parser.add_argument(
        "--ray-address",
        help="an existing Ray cluster, joined from one of its nodes (e.g. auto, or head:6379; "
        "a ray:// address needs Ray's client: pip install 'ray[client]'); implies ray",
    )
    parser.add_argument(
        "--workers", type=int, help="a local Ray's CPUs (default: this machine's cores)"
    )


def executor_from_args(args: argparse.Namespace) -> Executor:
    """The executor a command's ``add_executor_arguments`` options name."""
    if args.executor == "serial" and args.ray_address is not None:
        raise UserError("--ray-address is for --executor ray")
    if args.executor == "ray" or args.ray_address is not None:
        return RayExecutor(args.ray_address, args.workers)
    if args.workers is not None:
        raise UserError("--workers is for --executor ray")
    return SerialExecutor()
