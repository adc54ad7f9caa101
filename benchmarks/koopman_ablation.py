"""What the energy consistency loss buys: the shipped recipe trained without it, then exported
(outside the zoo) with the same error table and 10^5-step energy figures, for docs/KOOPMAN.md.

    python benchmarks/koopman_ablation.py --data runs/koopman-data --out runs/koopman-noenergy
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from membrane_models.learned.koopman_export import export_koopman
from membrane_models.learned.koopman_training import (
    KoopmanTrainConfig,
    network_config_for,
    train_koopman,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iterations", type=int, default=24000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    shipped = KoopmanTrainConfig(network=network_config_for(args.data, "aux", 10))
    config = dataclasses.replace(
        shipped, iterations=args.iterations, weights=(*shipped.weights[:4], 0.0)
    )
    run = train_koopman(config, args.data, args.out, command="benchmarks/koopman_ablation.py")
    assert run.checkpoint is not None
    manifest = export_koopman(run.checkpoint, args.out / "koopman-noenergy.onnx", args.data)
    print(manifest.table_text())
    print(json.dumps(manifest.errors["long_horizon"], indent=1))


if __name__ == "__main__":
    main()
