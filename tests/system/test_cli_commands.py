"""The `membrane` command as a new user meets it: real subprocesses against real servers on
loopback. Bad input is one line on stderr and exit code 2; the hints name command-line flags.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from membrane_models.problems import PROBLEMS, make_problem
from membrane_server.server import Server

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def membrane(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*MEMBRANE, *args], capture_output=True, text=True, timeout=60, cwd=cwd)


def one_line(result: subprocess.CompletedProcess[str]) -> str:
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


@pytest.fixture
def two_scene_server(start_server: Callable[..., Server], make_scene: Callable[..., Any]) -> Server:
    fields = {"lattice": {"nx": 5}, "placement": {"scale": 100.0}}
    return start_server(
        [
            make_scene("string-forced", "exact", name="left", **fields),
            make_scene("string-forced", "exact", name="right", **fields),
        ]
    )


# -- membrane serve --bind ---------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("bind", "expected"),
    [
        ("127.0.0.1:5555", "e.g. tcp://127.0.0.1:5555; got '127.0.0.1:5555'"),
        ("localhost:6000", "e.g. tcp://localhost:6000"),
        ("tcp://127.0.0.1", "tcp://HOST:PORT"),
        ("tcp://127.0.0.1:99999", "tcp://HOST:PORT"),
        ("udp://127.0.0.1:5555", "use a tcp:// (or ipc://) endpoint"),
    ],
)
def test_serve_bind_without_a_usable_endpoint_says_what_is_needed(bind: str, expected: str) -> None:
    result = membrane("serve", "--scene", "rope", "--bind", bind)
    assert result.returncode == 2
    line = one_line(result)
    assert line.startswith("membrane serve: error: --bind") and expected in line, line
    assert "CurveZMQ" not in result.stderr and "Invalid argument" not in result.stderr


# -- membrane serve: motion too small to see ---------------------------------------------------


@pytest.mark.slow
def test_serve_warns_when_the_motion_will_not_show(tmp_path: Path) -> None:
    scene = tmp_path / "patch.toml"
    scene.write_text(
        'model = "string-forced"\nevaluator = "exact"\ndt = 0.01\nduration = 1.0\n'
        "[lattice]\nnx = 20\n"  # placement.scale left at 1
    )
    process = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", str(scene), "--scene", "rope", "--bind",
         "tcp://127.0.0.1:*"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert process.stdout is not None
        assert "listening on" in process.stdout.readline()  # the warning is written before
    finally:
        process.terminate()
        _, err = process.communicate(timeout=30)
    warnings = [line for line in err.splitlines() if "WARNING" in line]
    assert len(warnings) == 1, err  # the file left at scale 1; not the built-in rope (100)
    assert f"scene {scene.resolve()}: spheres move by at most" in warnings[0]
    assert "set placement.scale to" in warnings[0]


# -- membrane query: unknown scene -------------------------------------------------------------


@pytest.mark.slow
def test_query_without_scene_on_a_multi_scene_server_names_the_flag(
    two_scene_server: Server,
) -> None:
    result = membrane("query", "--connect", two_scene_server.address, "--t", "0.5")
    assert result.returncode == 2
    line = one_line(result)
    assert line == (
        "membrane query: the server hosts several scenes (left, right): pass --scene NAME"
    )


@pytest.mark.slow
def test_query_of_an_unknown_scene_lists_the_hosted_ones(two_scene_server: Server) -> None:
    address = two_scene_server.address
    result = membrane("query", "--connect", address, "--t", "0.5", "--scene", "middle")
    assert result.returncode == 2
    line = one_line(result)
    assert line == (
        "membrane query: no scene 'middle' on the server: pass --scene with one of: left, right"
    )
    good = membrane("query", "--connect", address, "--t", "0.5", "--scene", "right")
    assert good.returncode == 0 and "scene right: step 50" in good.stdout


# -- membrane stats ----------------------------------------------------------------------------


@pytest.mark.slow
def test_stats_for_people_and_for_machines(two_scene_server: Server) -> None:
    address = two_scene_server.address
    for _ in range(3):
        query = membrane("query", "--connect", address, "--t", "0.2", "--scene", "left")
        assert query.returncode == 0, query.stderr
    as_json = membrane("stats", "--connect", address, "--json")
    assert as_json.returncode == 0, as_json.stderr
    stats = json.loads(as_json.stdout)
    assert stats["scenes"] == {"left": 3}
    assert stats["ops"]["query"] == 3 and stats["latency_us"]["count"] >= 6
    text = membrane("stats", "--connect", address)
    assert text.returncode == 0, text.stderr
    lines = text.stdout.splitlines()
    assert lines[0].startswith("up ") and " requests, " in lines[0]
    assert "query 3" in lines[1] and lines[2] == "queries by scene: left 3"
    assert lines[3] == "errors: none"
    assert lines[4].startswith("latency (us, receipt to reply, last ") and "p99 " in lines[4]


# -- membrane tradeoff --out -------------------------------------------------------------------


@pytest.mark.slow
def test_tradeoff_needs_out_and_writes_nothing_without_it(tmp_path: Path) -> None:
    result = membrane("tradeoff", "--quick", cwd=tmp_path)
    assert result.returncode == 2
    assert "--out" in one_line(result)
    assert list(tmp_path.iterdir()) == []  # no docs/ made in the current directory


# -- membrane exact --help ---------------------------------------------------------------------


@pytest.mark.slow
def test_exact_help_lists_every_problems_parameters() -> None:
    result = membrane("exact", "--help")
    assert result.returncode == 0
    for name in PROBLEMS:
        values = make_problem(name).parameters()
        line = next(x for x in result.stdout.splitlines() if x.strip().startswith(f"{name}: "))
        assert [item.split("=")[0] for item in line.split(": ", 1)[1].split(", ")] == list(values)
        for parameter in values:  # and says what each one means
            assert any(
                x.split()[:1] == [parameter] and len(x.split()) > 1
                for x in result.stdout.splitlines()
            )


def test_verbose_shows_the_traceback_behind_a_one_line_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Bad input is one line; with -v the traceback comes too, so that a bug that surfaces as a
    ValueError is not mistaken for a user's mistake."""
    from membrane_cli.dispatcher import main

    assert main(["serve", "--scene", "no-such-scene"]) == 2
    quiet = capsys.readouterr().err
    assert "unknown scene 'no-such-scene'" in quiet and "Traceback" not in quiet
    assert main(["-v", "serve", "--scene", "no-such-scene"]) == 2
    verbose = capsys.readouterr().err
    assert "Traceback (most recent call last)" in verbose and "SceneError" in verbose
