"""No frozen simulator: SIGINT and SIGTERM stop the simulation and release stepping; after a
SIGKILL the add-on (here the stand-in, which enforces its idle wait) forgets the vanished client
within the remote timeout the adapter sent, not the client library's 600 s."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from membrane_coppelia.interrupt import Interrupted, interrupt_on
from membrane_coppelia.options import RunOptions
from membrane_coppelia.probe import drive_probe
from membrane_coppelia.standin import CoppeliaStandin

DT = 0.001  # rope-live's: the stand-in starts with it, so no time-step warning on stderr


@pytest.fixture
def standin() -> Iterator[CoppeliaStandin]:
    with CoppeliaStandin(dt=DT) as server:
        tip = server.scene.create_dummy(0.01)
        server.scene.set_alias(tip, "tip")
        server.scene.set_position(tip, [0.5, 0.0, 0.99], -1)  # pressing the rope (at z = 1)
        yield server


def _wait_for(condition: Callable[[], bool], timeout: float, what: str) -> float:
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what} did not happen within {timeout} s")
        time.sleep(0.01)
    return time.monotonic() - start


def _stepping(standin: CoppeliaStandin) -> bool:
    return any(level > 0 for level in standin.stepping_levels().values())


def _released(standin: CoppeliaStandin) -> bool:
    return not standin.scene.running and not _stepping(standin)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_run_stops_the_simulation(
    rope_server: Any, standin: CoppeliaStandin, signum: int
) -> None:
    forces: list[float] = []

    def on_step(steps: int, t: float, force: float) -> None:
        forces.append(force)
        if steps == 20:  # delivered to the main thread wherever it is, likely mid-request
            threading.Timer(0.005, os.kill, (os.getpid(), signum)).start()

    with interrupt_on(), pytest.raises(Interrupted) as caught:
        options = RunOptions(server=rope_server.address, sim_port=standin.port)
        drive_probe("/tip", options, force_signal="f", on_step=on_step)
    assert caught.value.signum == signum and caught.value.simulator_released is True
    assert max(forces) > 0.0 and standin.scene.properties["signal.f"] == 0.0  # cleared
    assert _released(standin) and not standin.protocol.held()
    assert [o.alias for o in standin.scene.objects.values()] == ["tip"]  # lattice removed
    assert standin.scene.calls["sim.step"] >= 20


def test_interrupt_on_restores_the_handlers() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with interrupt_on():
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before


def _adapter(server: Any, standin: CoppeliaStandin, *extra: str) -> subprocess.Popen[str]:
    command = [
        sys.executable,
        "-m",
        "membrane_cli",
        "coppelia",
        "--connect",
        server.address,
        "--sim-port",
        str(standin.port),
        "--probe",
        "/tip",
        *extra,
    ]
    return subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ}
    )


@pytest.mark.slow
def test_cli_sigint_exits_130_with_one_line_and_the_simulator_released(
    rope_server: Any, standin: CoppeliaStandin
) -> None:
    process = _adapter(rope_server, standin)
    try:
        _wait_for(lambda: standin.scene.time > 0.02, 30.0, "the run")
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 130, err
    assert err.strip().splitlines() == [
        "membrane coppelia: interrupted by SIGINT: stopped the simulation (stepping released)"
    ]
    assert _released(standin)


@pytest.mark.slow
def test_after_sigkill_the_simulator_is_released_within_the_remote_timeout(
    rope_server: Any, standin: CoppeliaStandin
) -> None:
    remote_timeout = 1.0
    process = _adapter(rope_server, standin, "--remote-timeout", str(remote_timeout))
    try:
        _wait_for(lambda: standin.scene.time > 0.02 and _stepping(standin), 30.0, "the run")
        process.kill()  # SIGKILL: nothing of the adapter runs any more
        process.wait(timeout=10)
        killed = time.monotonic()
        time.sleep(0.2)
        assert standin.protocol.held()  # the vanished stepping client holds the simulation...
        frozen_at = standin.scene.time
        time.sleep(0.2)
        assert standin.scene.time == frozen_at
        _wait_for(lambda: not standin.protocol.held(), remote_timeout + 5.0, "the release")
        released_after = time.monotonic() - killed
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    # ... until the add-on forgets it: after the remote timeout, not 600 s.
    assert remote_timeout - 0.3 < released_after < remote_timeout + 2.0
    assert len(standin.protocol.forgotten) == 1
    _wait_for(lambda: standin.scene.time > frozen_at, 2.0, "the simulation running on")


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the swallowing
def test_a_signal_swallowed_by_a_finalizer_is_raised_again_by_the_run_loop() -> None:
    """A handler that runs inside a ``__del__`` raises into the void ("Exception ignored"): the
    run loops' ``raise_if_interrupted`` must raise it again, or the adapter runs on."""
    from membrane_coppelia.interrupt import Interrupted, interrupt_on, raise_if_interrupted

    class SignalsWhenCollected:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)

    with interrupt_on():
        SignalsWhenCollected()  # collected at once: the handler runs in its __del__
        with pytest.raises(Interrupted) as raised:
            raise_if_interrupted()
        assert raised.value.signum == signal.SIGINT
    raise_if_interrupted()  # outside the block nothing is pending


def test_a_swallowed_interrupt_is_kept_off_stderr_but_other_unraisables_are_not() -> None:
    """The swallowed Interrupted is not lost (the run loop raises it again), so printing
    "Exception ignored ... Interrupted" on Ctrl-C would only be noise; any other exception a
    finalizer loses is still reported."""
    from membrane_coppelia.interrupt import Interrupted, interrupt_on

    seen: list[type[BaseException] | type[None]] = []
    before = sys.unraisablehook
    sys.unraisablehook = lambda report: seen.append(type(report.exc_value))
    try:

        class Raises:
            def __init__(self, error: BaseException) -> None:
                self.error = error

            def __del__(self) -> None:
                raise self.error

        with interrupt_on():
            Raises(Interrupted(signal.SIGINT))
            Raises(ValueError("a finalizer's bug"))
        assert seen == [ValueError]
    finally:
        sys.unraisablehook = before
