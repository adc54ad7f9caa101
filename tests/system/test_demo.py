"""The README's main job: examples/demo.py runs end to end against a real server process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.py"


@pytest.mark.slow
def test_demo_polls_one_second_and_stops_the_server(tmp_path: Path) -> None:
    plot = tmp_path / "demo.png"
    result = subprocess.run(
        [sys.executable, str(DEMO), "--fast", "--plot", str(plot)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "scene membrane" in out
    assert "101 steps" in out
    assert "    50    0.50" in out and "<- peak" in out
    assert "client round trip over 101 queries: p50" in out
    assert "server stopped (exit code 0)" in out
    assert plot.stat().st_size > 10_000
