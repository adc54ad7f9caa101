"""The `membrane` command's core where no server is needed: `ping` and `stats` with nobody
answering, the stats summary's wording, and the dispatcher's handling of a command that cannot
load or has a bug. The core install (client and CLI) is all these need; the commands against real
servers are in tests/system/test_cli_commands.py and tests/server/test_server.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from membrane_cli.client_commands import stats_summary
from membrane_cli.dispatcher import main as membrane_main

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def membrane(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*MEMBRANE, *args], capture_output=True, text=True, timeout=60)


def one_line(result: subprocess.CompletedProcess[str]) -> str:
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


# -- ping and stats without a server ----------------------------------------------------------


def test_cli_ping_without_server_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    silent: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.ROUTER)  # never answers
    port = silent.bind_to_random_port("tcp://127.0.0.1")
    try:
        code = membrane_main(["ping", "--connect", f"tcp://127.0.0.1:{port}", "--timeout", "0.3"])
    finally:
        silent.close(linger=0)
    assert code == 1
    assert "no reply" in capsys.readouterr().err


@pytest.mark.slow
def test_stats_without_a_server_is_exit_1_in_one_line(tmp_path: Path) -> None:
    address = f"ipc://{tmp_path}/nobody"
    result = membrane("stats", "--connect", address, "--timeout", "0.2")
    assert result.returncode == 1
    assert one_line(result).startswith("membrane stats: ")


def test_stats_summary_wording_and_fields_it_does_not_know() -> None:
    reply = {"v": 1, "id": 7, "ok": True, "uptime_s": 3725.0, "requests": 0, "sessions": 0}
    summary = stats_summary({**reply, "extra": 1})
    assert summary.startswith("up 1 h 02 min, 0 requests, 0 sessions")
    assert "latency: no requests yet" in summary and "extra: 1" in summary.splitlines()
    assert not any(line.split(":")[0] in ("v", "id", "ok") for line in summary.splitlines())


# -- the dispatcher ---------------------------------------------------------------------------


def test_a_command_that_fails_to_load_is_reported_not_hidden(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from importlib.metadata import EntryPoint

    from membrane_cli import dispatcher

    broken = EntryPoint("broken", "membrane_cli.no_such_module:add", dispatcher.COMMAND_GROUP)
    monkeypatch.setattr(dispatcher, "entry_points", lambda group: [broken])
    assert dispatcher.main([]) == 2  # no command given: help, exit 2
    err = capsys.readouterr().err
    assert "membrane: command 'broken' cannot be loaded" in err
    assert "no_such_module" in err


def _add_buggy(subparsers: Any) -> None:
    """A command with a bug: a numpy shape error, a ValueError that is nobody's bad input."""
    parser = subparsers.add_parser("buggy")
    parser.set_defaults(handler=lambda args: int((np.zeros(3) + np.zeros(4)).sum()))


def _add_bad_import(subparsers: Any) -> None:
    """A command whose handler imports a module that no extra provides."""

    def handler(args: Any) -> int:
        import membrane_server.no_such_module  # noqa: F401

        return 0

    subparsers.add_parser("bad-import").set_defaults(handler=handler)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "add", "exception"),
    [
        ("buggy", "_add_buggy", "ValueError: operands could not be broadcast"),
        ("bad-import", "_add_bad_import", "ModuleNotFoundError"),
    ],
)
def test_a_bug_in_a_command_is_a_traceback_and_exit_1_not_bad_input(
    command: str,
    add: str,
    exception: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from importlib.metadata import EntryPoint

    from membrane_cli import dispatcher

    entry = EntryPoint(command, f"{__name__}:{add}", dispatcher.COMMAND_GROUP)
    monkeypatch.setattr(dispatcher, "entry_points", lambda group: [entry])
    with pytest.raises(BaseException) as raised:
        dispatcher.main([command])
    assert exception.split(":")[0] == type(raised.value).__name__
    # As the installed command runs it: the traceback on stderr, exit code 1, no "error:" line.
    script = (
        "import sys\n"
        "from importlib.metadata import EntryPoint\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from membrane_cli import dispatcher\n"
        f"entry = EntryPoint({command!r}, {f'{__name__}:{add}'!r}, dispatcher.COMMAND_GROUP)\n"
        "dispatcher.entry_points = lambda group: [entry]\n"
        f"sys.exit(dispatcher.main([{command!r}]))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 1, result.stderr
    assert "Traceback (most recent call last)" in result.stderr
    assert exception in result.stderr
    assert "bad input" not in result.stderr and f"membrane {command}: error" not in result.stderr
