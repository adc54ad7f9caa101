"""examples/haptic_hand.py against a real `membrane serve`: the simulated hand presses, slides
and lets go through the haptic loop, and its report is printed."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from serve_process import ServeProcess

pytestmark = pytest.mark.slow

HAND = Path(__file__).resolve().parents[2] / "examples" / "haptic_hand.py"


@pytest.fixture(scope="module")
def skin() -> Iterator[ServeProcess]:
    process = ServeProcess("skin-patch")
    yield process
    process.close()


def test_the_hand_presses_the_skin_through_the_loop(skin: ServeProcess, tmp_path: Path) -> None:
    plot = tmp_path / "hand.png"
    command = [sys.executable, str(HAND), "--connect", skin.address, "--scene", "skin-patch"]
    run = subprocess.run(
        [*command, "--plot", str(plot)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    held = next(line for line in lines if line.startswith("held while sliding"))
    stiffness = float(held.split(": ")[-1].split()[0])  # N/m
    # the coupled static stiffness, 5/6 of the patch's 301.8 N/m at its centre (the slide
    # crosses it), within the ringing of a damped, moving press
    assert 0.7 * 251.5 <= stiffness <= 1.3 * 251.5
    assert any(line.startswith("loop: 10") for line in lines)  # about 1,000 ticks
    pytest.importorskip("matplotlib")
    assert plot.stat().st_size > 10_000


def test_an_unknown_server_is_one_line_and_exit_2(tmp_path: Path) -> None:
    command = [sys.executable, str(HAND), "--connect", "tcp://127.0.0.1:1"]
    run = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.startswith("haptic_hand: ")
    assert len(run.stderr.strip().splitlines()) == 1
