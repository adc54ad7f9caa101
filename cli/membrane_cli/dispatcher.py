"""The `membrane` command: a small dispatcher over subcommands that each package registers.

Every package lists its subcommands in the ``membrane.commands`` entry-point group. An entry point
names a function ``add(subparsers)`` that adds one subparser and sets ``handler`` on it; the
function must import with the core dependencies alone, so that a client-only install still lists
every command. Heavy imports happen inside the handler: when one is missing the dispatcher says, in
one line, which extra to install.

Exit codes follow the exception tree of ``membrane_errors``:

- 0: success.
- 2: bad input: a ``UserError`` (one line), a file the command could not open (one line naming
  it), a missing extra (one line naming the extra to install).
- 1: the job failed: another ``MembraneError`` (one line), or a bug: any other exception, whose
  traceback is printed. ``-v`` prints the traceback of every failure.

A reader that stops early (``membrane query --t 0.5 --json | head``) ends every command quietly:
nothing on stderr, the rest of the output discarded, exit code 0 (not the shell's 141 for
SIGPIPE). The dispatcher handles this once, for every package's commands (see ``main``).
"""

from __future__ import annotations

import argparse
import logging
import os
import select
import sys
import traceback
from collections.abc import Callable, Sequence
from importlib import metadata
from importlib.metadata import entry_points
from typing import NoReturn

from membrane_cli.arguments import UsageError
from membrane_errors import MembraneError, UserError

__all__ = ["DISTRIBUTION", "EXTRA_FOR_MODULE", "OneLineParser", "UsageError", "main", "version"]

COMMAND_GROUP = "membrane.commands"

# Which extra brings in each optional top-level module (for the "install membrane-tissue[...]"
# hint). The distribution is `membrane-tissue`: `membrane` on the public index is another project.
DISTRIBUTION = "membrane-tissue"
EXTRA_FOR_MODULE: dict[str, str] = {
    "onnxruntime": "server",
    "pydantic": "server",
    "scipy": "server",
    "threadpoolctl": "server",
    "skfem": "server",
    "meshio": "server",
    "platformdirs": "server",
    "gmsh": "mesh",
    "torch": "train",
    "onnx": "train",
    "tqdm": "bench",
    "hdrh": "bench",
    "matplotlib": "plot",
    "aiohttp": "view",
    "coppeliasim_zmqremoteapi_client": "coppelia",
    "cbor2": "coppelia",
    "mujoco": "mujoco",
}


# Older installs carry the distribution's former name; the server's `hello` uses this too.
_DISTRIBUTIONS = (DISTRIBUTION, "membrane")

EPILOG = (
    "Exit codes: 0 success, 1 the job failed, 2 bad input, 130 interrupted. When the reader of "
    "the output goes away early (membrane query --t 0.5 --json | head), the command stops "
    "quietly with exit code 0."
)


def version() -> str:
    """'membrane X.Y.Z' from the installed distribution's metadata, as the server's ``hello``."""
    for distribution in _DISTRIBUTIONS:
        try:
            return f"membrane {metadata.version(distribution)}"
        except metadata.PackageNotFoundError:
            continue
    return "membrane (not installed)"


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="membrane",
        description="Real-time soft-tissue engine: physics-informed networks served over ZeroMQ.",
        epilog=EPILOG,
    )
    parser.add_argument("--version", action="version", version=version())
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="more logging (-vv), and the traceback of any failure",
    )
    subparsers = parser.add_subparsers(
        title="commands", dest="command", metavar="COMMAND", parser_class=OneLineParser
    )
    for entry in sorted(entry_points(group=COMMAND_GROUP), key=lambda e: e.name):
        try:
            add: Callable[[argparse._SubParsersAction[OneLineParser]], None] = entry.load()
        except Exception as exc:
            # A registration imports the core dependencies only, so this is a broken install or
            # a bug, never a missing extra: say so rather than drop the command from --help.
            print(f"membrane: command '{entry.name}' cannot be loaded: {_one_line(exc)}",
                  file=sys.stderr)  # fmt: skip
            continue
        add(subparsers)
    return parser


def _extra_for(exc: ModuleNotFoundError) -> str | None:
    return EXTRA_FOR_MODULE.get((exc.name or "").split(".")[0])


def _missing_extra_message(exc: ModuleNotFoundError) -> str:
    top = (exc.name or "").split(".")[0]
    extra = _extra_for(exc)
    return f"needs the '{extra}' extra: pip install '{DISTRIBUTION}[{extra}]' ({top} is missing)"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `membrane` command line; returns the process exit code.

    A reader of standard output that goes away (a closed pipe: ``| head``) ends the command
    quietly, as Python's documentation of SIGPIPE recommends: standard output is pointed at
    os.devnull, so that the interpreter's own flush at exit cannot fail again. Output cut short
    exits 0; a command that had finished keeps its own exit code. A broken pipe that is not
    standard output's (a socket, a child process) is not this case and keeps its traceback.
    """
    try:
        code = _run(argv)
    except BrokenPipeError:
        if not _stdout_reader_gone():
            raise
        _discard_stdout()
        return 0
    except SystemExit:  # argparse's --help, --version and usage errors: output still buffered
        _flush_stdout()
        raise
    _flush_stdout()
    return code


def _flush_stdout() -> None:
    """Flush what is buffered now, so that a closed pipe fails here, not at the interpreter's
    exit (a traceback-like message and exit code 120)."""
    if sys.stdout is None:
        return
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        if not _stdout_reader_gone():
            raise
        _discard_stdout()


def _stdout_reader_gone() -> bool:
    """Whether standard output is a pipe (or socket) whose reading end has been closed."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return False
    if not hasattr(select, "poll"):  # Windows: no poll; the error came from writing, trust it
        return True
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


def _discard_stdout() -> None:
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _run(argv: Sequence[str] | None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        return int(handler(args) or 0)
    except ModuleNotFoundError as exc:
        if _extra_for(exc) is None:
            raise  # not an extra's module: a broken install or a bug, with its traceback
        _traceback_if_verbose(args.verbose)
        print(f"membrane {args.command}: {_missing_extra_message(exc)}", file=sys.stderr)
        return 2
    except UserError as exc:
        return _one_line_failure(args, exc, 2, "error: ")
    except MembraneError as exc:
        return _one_line_failure(args, exc, 1)
    except OSError as exc:
        if exc.filename is None:
            raise  # not about a file the user named: a bug or the system's failure
        return _one_line_failure(args, exc, 2, "error: ")
    except KeyboardInterrupt:
        print(f"membrane {args.command}: interrupted", file=sys.stderr)
        return 130


def _one_line_failure(
    args: argparse.Namespace, exc: BaseException, code: int, prefix: str = ""
) -> int:
    _traceback_if_verbose(args.verbose)
    print(f"membrane {args.command}: {prefix}{_one_line(exc)}", file=sys.stderr)
    return code


def _traceback_if_verbose(verbose: int) -> None:
    if verbose:
        traceback.print_exc(file=sys.stderr)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
