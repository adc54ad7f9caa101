"""The README's commands, as written, on a fresh copy of the checkout.

The copy holds what a clone of this working tree would (tracked files and untracked ones git does
not ignore, uncommitted changes included), and no virtual environment. There the test runs
`make demo` (the set-up block's line), then every ```bash block of the README's "Run the server"
section ("By hand": one terminal with the server, a second one with the client commands), read
from README.md itself: each block is its own bash process, each line runs as written, and a
`membrane serve` line runs in the background and is stopped by its PID (SIGTERM) once every block
has run. The PATH is this test's without the directories that hold a `membrane` command, so a
block that does not activate the environment `make demo` made fails with "command not found".

pip uses the machine's configuration and cache, as `make demo` does anywhere. The README's server
binds tcp://127.0.0.1:5555, its default: when that port is taken the test is skipped. Measured:
22 s on a shared machine with a warm pip cache (`make demo` 19 s of it).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
SETUP_SECTION = "Set up on a fresh machine"
SERVER_SECTION = "Run the server"
README_PORT = 5555
MAKE_DEMO_TIMEOUT_S = 150.0
BLOCK_TIMEOUT_S = 60.0
# Environment a shell inherits that would make the copy less fresh than a new terminal.
DROPPED_ENV = ("VIRTUAL_ENV", "PYTHONHOME", "PYTHONPATH", "MAKEFLAGS", "MAKELEVEL", "MFLAGS")


def sections(markdown: str) -> dict[str, str]:
    """The text under each '## ' heading, by heading."""
    found: dict[str, str] = {}
    current: str | None = None
    for line in markdown.splitlines(keepends=True):
        if line.startswith("## "):
            current = line[3:].strip()
            found[current] = ""
        elif current is not None:
            found[current] += line
    return found


def bash_blocks(text: str) -> list[list[str]]:
    """The ```bash blocks of ``text``, as lists of their command lines (blank and comment-only
    lines left out)."""
    blocks = re.findall(r"^```bash\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    return [
        [line for line in block.splitlines() if line.strip() and not line.lstrip().startswith("#")]
        for block in blocks
    ]


def is_serve(line: str) -> bool:
    return shlex.split(line, comments=True)[:2] == ["membrane", "serve"]


@dataclass
class Step:
    block: int
    index: int
    line: str

    @property
    def key(self) -> str:
        return f"{self.block}-{self.index}"


def block_script(block: int, lines: list[str], out: Path) -> tuple[str, list[Step]]:
    """A bash script that runs ``lines`` as written, each with its stdout, stderr and exit code
    in files under ``out``; a `membrane serve` line runs in the background, its PID in a file,
    and the script goes on once the server says it listens (or has exited), then waits for it."""
    steps = [Step(block, index, line) for index, line in enumerate(lines)]
    script: list[str] = []
    servers: list[Step] = []
    for step in steps:
        files = f'> "{out}/{step.key}.out" 2> "{out}/{step.key}.err"'
        if is_serve(step.line):
            command = shlex.join(shlex.split(step.line, comments=True))  # the line less its comment
            script += [
                f"{command} {files} &",
                f'echo $! > "{out}/{step.key}.pid"',
                "for _ in $(seq 600); do",
                f'  grep -q "listening on" "{out}/{step.key}.out" && break',
                f'  kill -0 "$(cat "{out}/{step.key}.pid")" 2> /dev/null || break',
                "  sleep 0.1",
                "done",
            ]
            servers.append(step)
        else:
            script += ["{", step.line, f"}} {files}", f'echo $? > "{out}/{step.key}.rc"']
    script.append(f'command -v membrane > "{out}/{block}.which"')
    script.append(f'touch "{out}/{block}.ready"')
    for step in servers:
        script += [f'wait "$(cat "{out}/{step.key}.pid")"', f'echo $? > "{out}/{step.key}.rc"']
    return "\n".join(script) + "\n", steps


def copy_checkout(destination: Path) -> None:
    """What a clone of this working tree holds: tracked and untracked-not-ignored files."""
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
        timeout=60,
    ).stdout
    for name in filter(None, listed.decode().split("\0")):
        source = ROOT / name
        if not source.is_file() and not source.is_symlink():
            continue  # deleted in the working tree, not yet in the index
        target = destination / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target, follow_symlinks=False)


def fresh_shell_env() -> dict[str, str]:
    """This environment, less every PATH entry holding a `membrane` command (this test's venv
    among them) and less what an activated venv or an enclosing make set."""
    env = {key: value for key, value in os.environ.items() if key not in DROPPED_ENV}
    env["PATH"] = os.pathsep.join(
        entry
        for entry in env.get("PATH", "").split(os.pathsep)
        if entry and not (Path(entry) / "membrane").exists()
    )
    return env


def port_is_free(port: int) -> bool:
    with socket.socket() as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def is_our_server(pid: int) -> bool:
    """Whether ``pid`` is still a `membrane serve` process (not a reused PID)."""
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"serve" in command and any(word.endswith(b"membrane") for word in command)


def read(path: Path) -> str:
    return path.read_text() if path.exists() else f"<no {path.name}>"


def test_parsing_finds_bash_blocks_and_serve_lines() -> None:
    text = "## A\n\n```bash\nmembrane serve --scene x   # bg\n\n# note\nmembrane ping\n```\n"
    text += "```python\nprint()\n```\n## B\n```bash\nls\n```\n"
    found = sections(text)
    assert bash_blocks(found["A"]) == [["membrane serve --scene x   # bg", "membrane ping"]]
    assert bash_blocks(found["B"]) == [["ls"]]
    assert is_serve("membrane serve --scene x   # bg") and not is_serve("membrane ping")


def test_readme_run_the_server_as_written_on_a_fresh_copy(tmp_path: Path) -> None:
    readme = sections(README.read_text())
    setup = [line for block in bash_blocks(readme[SETUP_SECTION]) for line in block]
    make_demo = [line for line in setup if shlex.split(line, comments=True) == ["make", "demo"]]
    assert len(make_demo) == 1, setup
    blocks = bash_blocks(readme[SERVER_SECTION])
    assert any(is_serve(line) for block in blocks for line in block), blocks
    if not port_is_free(README_PORT):
        pytest.skip(f"port {README_PORT}, where the README's server binds, is in use")
    env = fresh_shell_env()
    if shutil.which("python3", path=env["PATH"]) is None:
        pytest.skip("no python3 on the PATH outside this test's virtual environment")

    clone, out = tmp_path / "membrane", tmp_path / "out"
    out.mkdir()
    copy_checkout(clone)
    started = time.monotonic()
    demo = subprocess.run(
        ["bash", "-c", make_demo[0]],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=MAKE_DEMO_TIMEOUT_S,
    )
    assert demo.returncode == 0, (demo.stdout[-3000:], demo.stderr[-3000:])
    assert "server stopped (exit code 0)" in demo.stdout, demo.stdout[-3000:]
    demo_s = time.monotonic() - started

    shells: list[subprocess.Popen[bytes]] = []
    steps: list[Step] = []
    try:
        for number, lines in enumerate(blocks):
            script, block_steps = block_script(number, lines, out)
            steps += block_steps
            shell = subprocess.Popen(["bash", "-c", script], cwd=clone, env=env)
            shells.append(shell)
            if any(is_serve(step.line) for step in block_steps):  # a terminal that stays open
                deadline = time.monotonic() + BLOCK_TIMEOUT_S
                while not (out / f"{number}.ready").exists() and shell.poll() is None:
                    assert time.monotonic() < deadline, f"block {number} did not get going"
                    time.sleep(0.05)
            else:
                shell.wait(timeout=BLOCK_TIMEOUT_S)
        for step in steps:  # stop each server by its PID, as one would Ctrl-C it
            if is_serve(step.line) and (out / f"{step.key}.pid").exists():
                # one that has exited already is no error here: its exit code says why
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(read(out / f"{step.key}.pid")), signal.SIGTERM)
        for shell in shells:
            shell.wait(timeout=BLOCK_TIMEOUT_S)
    finally:  # a server still running (a block that timed out): killed, if it is still ours
        if any(shell.poll() is None for shell in shells):
            for step in steps:
                pid_file = out / f"{step.key}.pid"
                if pid_file.exists() and is_our_server(int(read(pid_file))):
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(int(read(pid_file)), signal.SIGKILL)
        for shell in shells:
            if shell.poll() is None:
                shell.kill()
                shell.wait()
    total_s = time.monotonic() - started
    print(f"make demo {demo_s:.1f} s, all {total_s:.1f} s")

    for step in steps:
        stdout, stderr = read(out / f"{step.key}.out"), read(out / f"{step.key}.err")
        report = f"{step.line!r}: exit {read(out / f'{step.key}.rc').strip()}\n{stdout}\n{stderr}"
        assert read(out / f"{step.key}.rc").strip() == "0", report
        assert "Traceback" not in stderr, report
        if is_serve(step.line):
            assert "listening on tcp://127.0.0.1:5555" in stdout, report
            continue
        assert stderr == "", report
        if step.line.startswith("membrane "):
            assert stdout.strip(), report
        if "--json" in shlex.split(step.line, comments=True):
            json.loads(stdout)
    venv_bin = (clone / ".venv" / "bin").resolve()
    for number in range(len(blocks)):
        which = read(out / f"{number}.which").strip()
        assert which and Path(which).resolve().parent == venv_bin, f"block {number}: {which!r}"
