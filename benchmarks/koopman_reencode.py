"""What periodic re-encoding buys the Koopman network (docs/KOOPMAN.md, "Re-encoding").

    python benchmarks/koopman_reencode.py --data runs/koopman-data [--every 10,100,1000]
        [--steps 100000]

Re-encoding (Fathi et al., ICLR 2024) decodes the latent every N steps and encodes the state it
decodes to again, putting the latent back on the encoder's image. For the shipped model
(`models/membrane_models/zoo/koopman/`) on the test split (`membrane data koopman-string`),
without re-encoding and with it every N steps, prints:

1. the error at 1, 10, 100 and 1000 steps, as `membrane evaluate koopman-string` defines it,
   for smooth and rough shapes in the strong band and over all trajectories;
2. over ``--steps`` steps, the decoded energy against the reference's per family (its least
   and largest ratio) and the sines' error at the end (the Galerkin reference at rtol 1e-10).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from membrane_models.artifacts.koopman_evaluate import (
    TestSplit,
    error_table,
    long_horizon,
    onnx_rollout,
)
from membrane_models.artifacts.koopman_manifest import find_koopman_model

ROWS = (("smooth", "strong"), ("rough", "strong"), ("all", "all"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("runs/koopman-data"))
    parser.add_argument("--every", default="10,100,1000")
    parser.add_argument("--steps", type=int, default=100_000)
    args = parser.parse_args()
    manifest = find_koopman_model("koopman-string")
    assert manifest is not None, "the zoo's koopman-string model is missing"
    test = TestSplit.read(args.data / "test.npz")
    periods: list[int | None] = [None, *(int(n) for n in args.every.split(","))]
    print("| re-encoding | rows at 1 / 10 / 100 / 1000 steps: " +
          ", ".join(f"{f} {b}" for f, b in ROWS) + " |")  # fmt: skip
    print("| --- | --- |")
    for every in periods:
        table = error_table(onnx_rollout(manifest, every), test)
        cells = []
        for family, band in ROWS:
            row = next(r for r in table["rows"] if (r["family"], r["band"]) == (family, band))
            cells.append(" / ".join(f"{row['errors'][str(s)]:.3g}" for s in table["steps"]))
        print(f"| {every or 'none'} | " + "; ".join(cells) + " |", flush=True)
    print(f"\n| re-encoding | decoded / reference energy over {args.steps} steps, per family "
          "| sine error at the end (mean, largest) | seconds |")  # fmt: skip
    print("| --- | --- | --- | --- |")
    for every in periods:
        began = time.perf_counter()
        figures = long_horizon(manifest, test, args.steps, reencode=every)
        spans = ", ".join(f"{family} {low:.3f}-{high:.3f}" for family, (low, high)
                          in figures["energy_ratio_by_family"].items())  # fmt: skip
        print(
            f"| {every or 'none'} | {spans} | {figures['error_mean']:.3g}, "
            f"{figures['error_max']:.3g} | {time.perf_counter() - began:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
