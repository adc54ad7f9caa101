"""Peers that send requests and never read the replies: what the server holds for them.

Starts `membrane serve` on a scene, opens PEERS connections that each send REQUESTS `describe`
requests without reading, while a good client polls and checks every frame; prints the server's
peak RSS growth, its dropped-reply counters, its RSS after the peers leave (the server hands
freed memory back when idle) and the good client's failures. The figures in
docs/ROBUSTNESS.md ("Attacks") come from:

    python benchmarks/slow_readers.py --scene membrane --peers 400 --requests 1000
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "system"))

from attackers import GoodClient, MiB, WatchedServer, silent_dealers

from membrane_client import Client
from membrane_client.protocol import Request


def main(argv: list[str] | None = None) -> int:
    """Run the attack once and print its figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane")
    parser.add_argument("--peers", type=int, default=400)
    parser.add_argument("--requests", type=int, default=1000, help="describes per peer")
    parser.add_argument("--settle", type=float, default=5.0, help="seconds to let it answer")
    args = parser.parse_args(argv)
    server = WatchedServer([args.scene])
    try:
        good = GoodClient(server.address, args.scene).start()
        peers = silent_dealers(server.address, args.peers)
        describe = Request("describe", 1).to_wire()
        for _ in range(args.requests):
            for peer in peers:
                peer.send_multipart([b"", describe])
        time.sleep(args.settle)
        with Client(server.address, timeout=5.0) as client:
            stats = client.stats()
        print(
            f"{args.peers} peers x {args.requests} describes on {args.scene}: "
            f"{stats.requests} answered, dropped {stats.dropped_replies}"
        )
        print(f"server RSS: peak +{server.growth() / MiB:.0f} MiB over {server.baseline / MiB:.0f}")
        for peer in peers:
            peer.close()
        time.sleep(8.0)  # idle: the server returns freed memory within 5 s
        after = (server.rss() - server.baseline) / MiB
        print(f"server RSS 8 s after the peers left: +{after:.0f} MiB")
        good.stop()
        print(f"good client: {good.answered} frames checked, {len(good.failures)} failures")
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
