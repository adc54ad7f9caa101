"""The haptic loop against a real `membrane serve`: a real servo thread, its network side in a
process of its own, a scripted device. Passivity over closed cycles, no chatter on a slow press,
and rendering through a stalled server (SIGSTOP for 100 ms) from the sent compliance."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from serve_process import ServeProcess

from membrane_client.haptics import HapticLoop, HapticReport, Tick

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs SIGSTOP"),
]

SCENE, AT, RADIUS = "membrane-live", (0.5, 0.5), 0.05
PERIOD = 1e-3


class Device:
    """A scripted hand: depth ``script[n]`` at the loop's n-th tick, or ``hold`` once set."""

    def __init__(self, script: np.ndarray, at: tuple[float, float] = AT) -> None:
        self.script, self.at, self.calls = script, at, 0
        self.hold: float | None = None
        self.lock = threading.Lock()

    def __call__(self) -> tuple[float, float, float]:
        with self.lock:
            n, self.calls = self.calls, self.calls + 1
            depth = (
                self.hold if self.hold is not None else self.script[min(n, self.script.size - 1)]
            )
        return (*self.at, float(depth))


@pytest.fixture(scope="module")
def server() -> Iterator[ServeProcess]:
    process = ServeProcess(SCENE)
    yield process
    process.close()


def _run(server: ServeProcess, script: np.ndarray) -> tuple[list[Tick], HapticReport]:
    ticks: list[Tick] = []
    loop = HapticLoop(server.address, SCENE, Device(script), radius=RADIUS, render=ticks.append)
    with loop:
        while len(ticks) < script.size:
            time.sleep(0.01)
    return ticks[: script.size], loop.report()


def test_over_twenty_press_release_cycles_the_device_gains_no_energy(
    server: ServeProcess,
) -> None:
    t = np.arange(2000) * PERIOD
    script = 1e-3 * (1 - np.cos(2 * math.pi * 10 * t)) / 2  # 20 presses to 1e-3 at 10 Hz
    ticks, report = _run(server, script)
    depths = np.array([tick.device for tick in ticks])
    forces = np.array([tick.force for tick in ticks])
    work = float(np.sum(forces[:-1] * np.diff(depths)))  # the hand's on the device, J-like
    assert report.steps > 100 and forces.max() > 0.01
    assert work >= -1e-12 * float(np.abs(forces[:-1] * np.diff(depths)).sum())


def test_a_slow_press_never_lets_go_nor_spikes(
    server: ServeProcess,
) -> None:
    ramp = np.linspace(0.0, 1e-3, 201)[1:]  # poke.py's ramp: 1e-3 over 0.2 s, then held
    script = np.concatenate([ramp, np.full(800, 1e-3)])
    ticks, _ = _run(server, script)
    forces = np.array([tick.force for tick in ticks])
    # no chatter: below the surface from the first tick, and pressed from it (the network side
    # sends a contact before the loop's first tick)
    assert (forces > 0).all()
    settled = 1e-3 / (0.014772 * 6 / 5)  # the coupled static force at full depth, 0.0564
    # this press is shorter than membrane-live's slowest period (0.28 s): a rigid tip's exact
    # force bounces to 0 and back and reaches 465 times the static force at its depth in the
    # first 5 ms (docs/HAPTICS.md, "Limits"); through the coupling the largest was 1.3 to 1.7
    # times the settled force, more when the network side skips steps (the tissue lags)
    assert forces.max() <= 2.0 * settled and forces[-400:].min() >= 0.4 * settled


@pytest.fixture(scope="module")
def skin() -> Iterator[ServeProcess]:
    process = ServeProcess("skin-patch")
    yield process
    process.close()


def test_a_slow_press_on_the_skin_patch_follows_its_static_stiffness(skin: ServeProcess) -> None:
    # 1 mm at 5 mm/s, held: 16 of the patch's slowest periods (81.7 Hz), a slow press for it
    depth = np.minimum(np.arange(1, 501) / 200, 1.0) * 1e-3
    ticks: list[Tick] = []
    device = Device(depth, at=(0.025, 0.025))
    loop = HapticLoop(skin.address, "skin-patch", device, render=ticks.append)
    with loop:
        while len(ticks) < depth.size:
            time.sleep(0.01)
    forces = np.array([tick.force for tick in ticks[: depth.size]])
    devices = np.array([tick.device for tick in ticks[: depth.size]])
    static = loop.contact.static_compliance  # 1 / 301.8 N/m at the centre
    quasi_static = devices / (static * 6 / 5)  # the coupled static force at each tick's depth
    assert (forces > 0).all()  # pressed from the first tick, never let go
    # from 50 ms on within 1.2 times the quasi-static force (measured 1.05 to 1.11); before,
    # the plate's inertia: its drive-point impedance 8 sqrt(D rho h) = 0.95 N s/m times 5 mm/s
    # is 4.7 mN, 3.3 times the static force of the first millisecond's 5 um (a rigid tip's
    # exact force), and the network side's skipped steps make the tissue lag (2.3 times)
    ratio = forces / quasi_static
    assert ratio[50:].max() <= 1.2, f"{ratio[50:].max():.3f}"
    assert ratio[-100:] == pytest.approx(1.0, abs=0.02)


def test_while_the_server_is_stopped_the_loop_renders_from_the_sent_compliance(
    server: ServeProcess,
) -> None:
    device = Device(np.linspace(0.0, 5e-4, 100))
    ticks: list[Tick] = []
    loop = HapticLoop(server.address, SCENE, device, radius=RADIUS, render=ticks.append)
    with loop:
        time.sleep(0.4)
        os.kill(server.process.pid, signal.SIGSTOP)
        try:
            time.sleep(0.03)  # the last contact is now stale
            before = ticks[-1]
            with device.lock:
                device.hold = 5.5e-4
            time.sleep(0.03)
            during = ticks[-1]
            contact = loop.contact
        finally:
            os.kill(server.process.pid, signal.SIGCONT)
        resumed = len(ticks)
        time.sleep(0.3)
        after = ticks[resumed:]
    report = loop.report()
    assert before.stale and during.stale and during.k == before.k  # no step arrived
    k, _ = loop.coupling.gains(contact, PERIOD)
    expected = 5e-5 / (contact.compliance + 1 / k)  # the coupled one-step stiffness
    assert during.force - before.force == pytest.approx(expected, rel=0.02)
    # stepping again: fresh contacts arrive (each tick stale or not, as the machine allows)
    assert after[-1].k > during.k and sum(not tick.stale for tick in after) > 0
    assert report.skipped >= 60 and report.error is None  # the stopped 100 ms were skipped
