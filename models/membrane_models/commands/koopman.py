"""`membrane train|export|evaluate koopman-string`: the Koopman latent model's commands.

`membrane train` hands a ``koopman-string`` run here (its flags are shared with the PINNs';
``--data`` names the dataset, ``--arch`` is ``aux`` or ``fixed``). Imports of torch happen in
the handlers, as everywhere in the commands.
"""

from __future__ import annotations

import argparse
import logging
import shlex
from pathlib import Path
from typing import Any

from membrane_cli.arguments import UsageError

__all__ = [
    "KOOPMAN_MODEL",
    "is_koopman_checkpoint",
    "koopman_train_command",
    "run_koopman_evaluate",
    "run_koopman_export",
    "run_koopman_train",
]

KOOPMAN_MODEL = "koopman-string"
_ARCHES = ("aux", "fixed")


def koopman_train_command(args: argparse.Namespace, arch: str) -> str:
    """The canonical command line of a Koopman run (stored in checkpoints and manifests)."""
    parts = ["membrane", "train", KOOPMAN_MODEL, "--arch", arch, "--data", str(args.data)]
    if args.iterations is not None:
        parts += ["--iterations", str(args.iterations)]
    parts += ["--seed", str(args.seed), "--out", str(args.out)]
    return shlex.join(parts)


def run_koopman_train(args: argparse.Namespace) -> int:
    import torch

    from membrane_models.learned.koopman_training import (
        KoopmanTrainConfig,
        network_config_for,
        train_koopman,
    )

    arch = "aux" if args.arch in (None, "spinn") else args.arch
    if arch not in _ARCHES:
        raise UsageError(f"--arch for {KOOPMAN_MODEL} must be one of {', '.join(_ARCHES)}")
    if args.data is None:
        raise UsageError(f"{KOOPMAN_MODEL} needs --data DIR (`membrane data koopman-string`)")
    if args.sets or args.lbfgs_fraction is not None or args.monitor_every:
        raise UsageError(f"{KOOPMAN_MODEL} takes no --set, --lbfgs-fraction or --monitor-every")
    changes: dict[str, Any] = {"seed": args.seed}
    if args.iterations is not None:
        if args.iterations <= 0:
            raise UsageError(f"--iterations must be > 0, got {args.iterations}")
        changes["iterations"] = args.iterations
    network = network_config_for(args.data, arch, pairs=10)
    config = KoopmanTrainConfig(network=network, **changes)
    args.out.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(args.out / "train.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    train_logger = logging.getLogger("membrane_models")
    train_logger.addHandler(handler)
    train_logger.setLevel(logging.INFO)
    propagate = train_logger.propagate
    train_logger.propagate = getattr(args, "verbose", 0) > 0
    torch.set_num_threads(1)  # small networks on a shared CPU (see `membrane train`)
    command = koopman_train_command(args, arch)
    try:
        logging.getLogger(__name__).info("command: %s", command)
        run = train_koopman(
            config,
            args.data,
            out_dir=args.out,
            command=command,
            resume=args.resume,
            progress=not args.no_progress,
        )
    finally:
        train_logger.removeHandler(handler)
        train_logger.propagate = propagate
        handler.close()
    last = run.history[-1] if run.history else {}
    terms = " ".join(f"{k}={v:.3e}" for k, v in last.items() if k not in ("iteration", "wall_time"))
    print(f"trained {run.iterations} iterations in {run.wall_time:.1f} s: {terms}")
    print(f"checkpoint: {run.checkpoint}")
    return 0


def is_koopman_checkpoint(path: Path) -> bool:
    """Whether ``path`` holds a Koopman checkpoint (read with torch's safe loader)."""
    import torch

    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # not ours to judge here: the PINN export reports it
        return False
    return isinstance(data, dict) and "koopman_format" in data


def run_koopman_export(args: argparse.Namespace) -> int:
    from membrane_models.learned.koopman_export import export_koopman

    data = getattr(args, "data", None)
    manifest = export_koopman(args.checkpoint, args.out, data)
    print(f"wrote {manifest.name}: encoder, step and decoder graphs and {manifest.name}.json")
    print(manifest.table_text())
    return 0


def run_koopman_evaluate(args: argparse.Namespace, manifest: Any) -> int:
    """Print a Koopman model's error table (the manifest's, or re-measured on ``--data``)."""
    import json

    from membrane_models.artifacts.koopman_evaluate import error_table, onnx_rollout

    data = getattr(args, "data", None)
    if data is not None:
        table = error_table(onnx_rollout(manifest), Path(data) / "test.npz")
        manifest = manifest.with_errors(table)
    if args.json:
        print(json.dumps(manifest.errors, indent=2))
    else:
        where = f"re-measured on {data}" if data is not None else "as recorded in its manifest"
        print(f"{manifest.name} ({manifest.problem}), {where}:")
        print(manifest.table_text())
    return 0
