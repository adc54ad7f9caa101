"""The haptic loop's network side, a process of its own: it steps a live session at the
scene's rate with the force the device side last rendered and hands each reply's contact to it
(``channel``).

Each step applies the rendered force as a load on the tip's footprint (pressing along -axis),
so the tissue gets exactly the force the device felt, and asks for the step's look-ahead
through a probe held clear of the tissue (``MAX_DEPTH`` above it): its reading gives the
one-step compliance c under the tip and the next step's free displacement with this step's
load held, from which the tip's own share is taken back out (+ c F), leaving the free
displacement z the device side solves the next step's contact with. Force-driven rather than
position-driven on purpose: the one-step stiffness under a tip is hundreds of times the static
one (membrane-live: 31,500 against 68), so a depth one servo tick older than the device side's
would make the server's contact and the rendered one disagree by most of the force; a force
is the same number on both sides.

Run by ``HapticLoop`` as ``python -m membrane_client.haptics.network``: in a process of its
own, so that nothing it does (a socket wait, a reply's decoding, a garbage collection) holds
the device side's interpreter lock (a Python thread may hold it for its 5 ms switch interval).

Each step waits for the device side to have rendered from the last reply: a force rendered
from an older contact was the force that held the tissue for that older step, and applied
again it would push the tissue twice (unstable on a stiff one-step response).

Tissue time follows wall time: step k is taken at start + k dt of this process's clock. After
a stall (the server paused, the machine busy) the steps whose time has passed are not replayed
one after another to catch up; they are skipped and counted (``ContactRecord.skipped``), and
the next step is taken at once, so the tissue lags wall time by the skipped steps' dt rather
than racing. A step whose every reply was lost (``StepLost``) is counted (``lost``) and the
session's count follows the server's.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from membrane_client.client import Client
from membrane_client.errors import MembraneError, StepLost
from membrane_client.haptics.channel import Channel, ContactRecord, State
from membrane_client.live_schema import MAX_DEPTH, Load, Probe
from membrane_client.session import Session

__all__ = ["main", "step_at_wall_rate"]

_IDLE_S = 0.0005  # the wait between looks for the device's first position
_MAX_SLEEP_S = 0.02  # so that a stop request is seen within this


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    channel = Channel.open(Path(args.channel))
    try:
        client = Client(args.address, timeout=args.timeout, retries=args.retries)
        with client, client.session(args.scene) as session:
            assert session.info is not None
            channel.dt = session.info.dt
            tally = _Tally()
            at = tuple(args.at[: args.dims])
            # a first step before the device's clock starts: its first tick has a contact
            if not _step(session, channel, at, 0.0, args.radius, tally):
                raise MembraneError("the first step's replies were lost")
            channel.state = State.RUNNING
            step_at_wall_rate(session, channel, session.info.dt, args.radius, args.dims, tally)
        channel.state = State.STOPPED
        return 0
    except MembraneError as error:  # a refusal, a dead server: the device side reports it
        channel.state = State.FAILED
        print(f"membrane haptics: {error}", file=sys.stderr, flush=True)
        return 2
    finally:
        channel.close()


@dataclass
class _Tally:
    steps: int = 0
    skipped: int = 0
    lost: int = 0
    taken: int = 0  # the session's step count after the last reply


def step_at_wall_rate(
    session: Session, channel: Channel, dt: float, radius: float, dims: int, tally: _Tally
) -> None:
    """Step ``session`` every ``dt`` of wall time with the proxy's position until the device
    side asks to stop (module docstring)."""
    while channel.read_proxy(dims) is None:  # the clock starts with the device
        if channel.stop_requested:
            return
        time.sleep(_IDLE_S)
    due = time.monotonic()
    while not channel.stop_requested:
        now = time.monotonic()
        if now < due:
            time.sleep(min(due - now, _MAX_SLEEP_S))
            continue
        behind = int((now - due) / dt)
        if behind:  # a stall: those steps' time has passed, take the next one now
            tally.skipped += behind
            due += behind * dt
        proxy = channel.read_proxy(dims)
        if proxy is None or proxy[3] < tally.taken:  # not yet rendered from the last reply
            time.sleep(_IDLE_S)
            continue
        at, _, force, _ = proxy
        _step(session, channel, at, force, radius, tally)
        due += dt


def _step(
    session: Session,
    channel: Channel,
    at: tuple[float, ...],
    force: float,
    radius: float,
    tally: _Tally,
) -> bool:
    """One step with ``force`` on the tip's footprint; its contact into the channel. False
    when every reply was lost (counted)."""
    try:
        frame = session.step(
            [Load(at, -force, radius)] if force > 0.0 else [],
            [Probe(at, -MAX_DEPTH, radius)],
            frame=False,
            lookahead=True,
        )
    except StepLost:
        tally.lost += 1
        return False
    tally.steps, tally.taken = tally.steps + 1, frame.k
    reading = frame.probes[0]
    record = ContactRecord(
        frame.k,
        reading.next_free + reading.compliance * force,
        reading.compliance,
        reading.static_compliance,
        force,
        time.monotonic(),
        tally.steps,
        tally.skipped,
        tally.lost,
    )
    channel.write_contact(record)
    return True


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m membrane_client.haptics.network")
    parser.add_argument("--address", required=True)
    parser.add_argument("--scene", required=True)
    parser.add_argument("--channel", required=True, help="the shared block's file")
    parser.add_argument("--radius", type=float, default=0.0)
    parser.add_argument("--dims", type=int, choices=(1, 2), default=2)
    parser.add_argument(
        "--at", type=float, nargs="+", default=[0.0, 0.0], help="the tip's first x [y]"
    )
    parser.add_argument("--timeout", type=float, default=0.25)
    parser.add_argument("--retries", type=int, default=2)
    return parser


if __name__ == "__main__":
    sys.exit(main())
