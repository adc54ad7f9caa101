"""`membrane keys`: make a CurveZMQ key pair whose secret file only its owner can read."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import zmq.auth

from membrane_client.curve import CurveError

__all__ = ["add_keys", "create_keypair"]

_OWNER_ONLY = 0o600


def add_keys(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane keys`."""
    parser = subparsers.add_parser(
        "keys",
        help="make a CurveZMQ key pair (NAME.key, NAME.key_secret mode 0600)",
        description=(
            "Write DIR/NAME.key (the public key, to hand out) and DIR/NAME.key_secret (both "
            "keys, readable by you only). A server needs its own pair and a folder of its "
            "clients' .key files; each client needs its own pair and the server's .key."
        ),
    )
    parser.add_argument("directory", metavar="DIR", help="folder to write the key files into")
    parser.add_argument("name", metavar="NAME", help="key name, e.g. server or robot-1")
    parser.set_defaults(handler=_run_keys)


def _run_keys(args: argparse.Namespace) -> int:
    public, secret = create_keypair(args.directory, args.name)  # CurveError: a UserError, exit 2
    print(f"wrote {public} (public) and {secret} (secret, mode 0600)")
    return 0


def create_keypair(directory: str | Path, name: str) -> tuple[Path, Path]:
    """Write ``NAME.key`` (public, 0644) and ``NAME.key_secret`` (0600) into ``directory``.

    The files are written in a private temporary folder and moved into place, so the secret key
    is never readable by others, not even for an instant (``zmq.auth.create_certificates`` alone
    leaves it to the umask, 0644 on most systems).

    Raises:
        CurveError: ``name`` is not a plain file stem, or a key file of that name exists.
    """
    folder = Path(directory)
    if not name or Path(name).name != name or name.startswith("."):
        raise CurveError(f"key name {name!r}: give a plain name such as 'server' or 'robot-1'")
    public, secret = folder / f"{name}.key", folder / f"{name}.key_secret"
    for existing in (public, secret):
        if existing.exists():
            raise CurveError(f"{existing}: exists; remove it first to make a new key pair")
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder, prefix=".keys-") as private:  # mode 0700
        made_public, made_secret = zmq.auth.create_certificates(private, name)
        os.chmod(made_secret, _OWNER_ONLY)
        os.chmod(made_public, 0o644)
        os.replace(made_secret, secret)
        os.replace(made_public, public)
    return public, secret
