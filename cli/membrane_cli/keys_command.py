"""`membrane keys`: make a CurveZMQ key pair whose secret file only its owner can read."""

from __future__ import annotations

import argparse

__all__ = ["add_keys"]


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
    from membrane_client.curve import create_keypair

    public, secret = create_keypair(args.directory, args.name)  # CurveError: a UserError, exit 2
    print(f"wrote {public} (public) and {secret} (secret, mode 0600)")
    return 0
