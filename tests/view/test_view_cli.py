"""`membrane view` and `membrane animate` from the command line: bad input is one line and exit
code 2; animations of a film and of a poke on a live scene are written as GIFs."""

from __future__ import annotations

from pathlib import Path

import pytest

from membrane_cli.dispatcher import main as membrane_main
from membrane_server.server import Server


def _run(argv: list[str]) -> int:
    try:
        return membrane_main(argv)
    except SystemExit as exc:  # argparse's own errors
        return int(exc.code or 0)


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["view", "--port", "70000"], "--port"),
        (["view", "--port", "x"], "--port"),
        (["view", "--fps", "0"], "--fps"),
        (["view", "--speed", "nan"], "--speed"),
        (["view", "--host", "not-an-ip"], "--host"),
        (["view", "--max-connections", "0"], "--max-connections"),
        (["view", "--max-connections", "65"], "--max-connections"),
        (["animate", "--scene", "membrane", "--out", "clip.txt"], ".gif or .mp4"),
        (["animate", "--scene", "membrane", "--out", "/no/such/dir/a.gif"], "no such directory"),
        (["animate", "--out", "a.gif"], "--scene"),
        (["animate", "--scene", "membrane", "--out", "a.gif", "--fps", "-1"], "--fps"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(argv) == 2
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith("usage:")]
    assert len(lines) == 1 and says in lines[0], err


def test_an_mp4_without_ffmpeg_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from matplotlib import animation

    monkeypatch.setattr(animation.FFMpegWriter, "isAvailable", classmethod(lambda cls: False))
    out = tmp_path / "a.mp4"
    assert _run(["animate", "--scene", "membrane", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ffmpeg" in err
    assert not out.exists()


def test_a_port_in_use_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert _run(["view", "--port", str(port), "--connect", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert f"cannot serve on 127.0.0.1:{port}" in err[-1]


@pytest.mark.parametrize("token", ["short", "x" * 257, "has spaces in it, sixteen+", "é" * 20])
def test_a_bad_token_from_the_environment_is_one_line(
    token: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    monkeypatch.setenv("MEMBRANE_VIEW_TOKEN", token)
    with socket.socket() as taken:  # were the token taken, the port in use still ends the run
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        assert _run(["view", "--port", port, "--connect", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "$MEMBRANE_VIEW_TOKEN must be 16 to 256" in err[0], err
    assert token not in err[0]


def _frames(path: Path) -> int:
    from PIL import Image

    with Image.open(path) as image:
        return int(getattr(image, "n_frames", 1))


@pytest.mark.slow
def test_animate_a_film_to_gif(membrane_server: Server, tmp_path: Path) -> None:
    out = tmp_path / "film.gif"
    argv = ["animate", "--connect", membrane_server.address, "--scene", "membrane"]
    assert _run([*argv, "--out", str(out), "--fps", "10", "--speed", "1"]) == 0
    assert _frames(out) == 11  # 1 s at 10 frames per second, both ends


@pytest.mark.slow
def test_animate_a_poke_on_a_live_scene_to_gif(live_server: Server, tmp_path: Path) -> None:
    out = tmp_path / "poke.gif"
    argv = ["animate", "--connect", live_server.address, "--scene", "rope-live"]
    assert _run([*argv, "--out", str(out), "--fps", "10", "--speed", "1"]) == 0
    assert _frames(out) == 8  # 0.8 s of poke and ringing at 10 frames per second


@pytest.mark.slow
def test_membrane_view_serves_the_page_from_the_command(
    membrane_server: Server, tmp_path: Path
) -> None:
    import os
    import re
    import subprocess
    import sys
    import urllib.error
    import urllib.request

    command = [sys.executable, "-c", "import sys; from membrane_cli.dispatcher import main; "
               "sys.exit(main(sys.argv[1:]))", "view", "--port", "0", "--connect",
               membrane_server.address, "--scene", "membrane"]  # fmt: skip
    token = "a-fixed-token_0123456789"
    env = {**os.environ, "MEMBRANE_VIEW_TOKEN": token}
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert process.stderr is not None
        line = process.stderr.readline()
        match = re.search(r"http://127\.0\.0\.1:(\d+)/\?token=(\S+) ", line)
        assert match and int(match.group(1)) > 0 and match.group(2) == token, line
        with urllib.request.urlopen(match.group(0).strip(), timeout=10) as reply:
            assert '<canvas id="surface"' in reply.read().decode()
        without = match.group(0).split("?")[0]
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(without, timeout=10)
        assert refused.value.code == 403
    finally:
        process.terminate()
        process.wait(timeout=20)
