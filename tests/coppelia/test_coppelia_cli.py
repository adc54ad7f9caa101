"""`membrane coppelia` on a film: its output and its exit codes (the probe's are in
test_coppelia_probe.py, the signals' in test_coppelia_interrupt.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from typing import Any

import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")


from membrane_cli.dispatcher import main as membrane_main
from membrane_coppelia.standin import CoppeliaStandin


@pytest.mark.slow  # over a second: the full suite runs it
def test_cli_runs_half_a_second(
    standin: CoppeliaStandin, membrane_server: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["coppelia", "--connect", membrane_server.address, "--sim-port", str(standin.port)]
    assert membrane_main([*argv, "--duration", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "scene membrane: 400 spheres moved batched: 51 steps, t = 0 .. 0.5 s" in out
    assert "per step p50/p99: read " in out and " step " in out
    assert standin.scene.calls["sim.step"] == 51 and standin.scene.objects == {}


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--duration", "-1"], "--duration: must be >= 0"),
        (["--sim-port", "70000"], "--sim-port: must be in 1..65535"),
        (["--color", "1,2"], "--color: expected 3 values"),
        (["--sim-timeout", "0"], "--sim-timeout: must be a positive number"),
        (["--scene", "nope"], "unknown_scene"),
    ],
)
def test_cli_bad_input_exits_2(
    standin: CoppeliaStandin,
    membrane_server: Any,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    argv = ["coppelia", "--connect", membrane_server.address, "--sim-port", str(standin.port)]
    assert _exit_code([*argv, *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def _exit_code(argv: list[str]) -> int:
    """`membrane` in-process: argparse errors exit (SystemExit), handlers return their code."""
    try:
        return membrane_main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


@pytest.mark.slow
def test_cli_exits_1_without_hanging_when_coppeliasim_stops_answering(
    membrane_server: Any,
) -> None:
    with CoppeliaStandin(answer_limit=100) as hung:
        command = [
            sys.executable,
            "-m",
            "membrane_cli",
            "coppelia",
            "--connect",
            membrane_server.address,
            "--sim-port",
            str(hung.port),
            "--sim-timeout",
            "0.5",
        ]
        result = subprocess.run(
            command, capture_output=True, text=True, timeout=60, env={**os.environ}
        )
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "did not answer within 0.5 s" in lines[0]
