"""`membrane caches`: build the FEM caches of scenes (and of their material variants) ahead of
serving them, one after another or as Ray tasks.

This module imports with the core dependencies only; the scenes, the fem room and Ray are
imported when the command runs.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from membrane_errors import UserError
from membrane_models.executors import Job, add_executor_arguments, executor_from_args

if TYPE_CHECKING:
    from membrane_server.cache_build import SceneCaches

__all__ = ["add_caches"]

_EPILOG = """\
examples:
  membrane caches --scene skin-patch --scene skin-disk
  membrane caches --scene skin-patch --vary tissue.youngs_modulus=1e6,1.5e6,2e6 \\
      --vary tissue.thickness=0.002,0.003 --executor ray

Each variant is loaded as `membrane serve` loads a scene, so a server of that variant later
finds its tables in milliseconds. On a cluster (--ray-address) the cache directory must be one
every node sees (a shared filesystem): the command checks that each job's entries are there."""


def add_caches(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane caches`."""
    parser = subparsers.add_parser(
        "caches",
        help="build the FEM caches of scenes and their material variants before serving them",
        description=(
            "Load each scene (and each combination of the --vary values) as the server would, "
            "so that its FEM tables (modes, footprints, static correction; a nonlinear scene's "
            "reduced plate) are found in the cache, or built and stored there. One job per "
            "variant: one after another here, or as Ray tasks with --executor ray."
        ),
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--scene", action="append", required=True, metavar="NAME|FILE",
        help="a scene (built-in name or TOML file); repeat for several",
    )  # fmt: skip
    parser.add_argument(
        "--vary", action="append", default=[], metavar="KEY=V1,V2,...",
        help="a scene field's values, e.g. tissue.youngs_modulus=1e6,2e6 (SI, as in the scene "
        "file; TOML values: a list in brackets, a string in quotes); repeat for the product "
        "of several",
    )  # fmt: skip
    parser.add_argument(
        "--cache-dir", type=Path, metavar="ROOT",
        help="the caches' root, as MEMBRANE_CACHE_DIR (the tables go to ROOT/fem; a server "
        "finds them with MEMBRANE_CACHE_DIR=ROOT; default: $MEMBRANE_CACHE_DIR, else the user "
        "cache)",
    )  # fmt: skip
    add_executor_arguments(parser)
    parser.set_defaults(handler=_run_caches)


def _require_writable(folder: Path) -> None:
    """Make ``folder`` and write a file in it, or say in one line why not, before any build."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, suffix=".tmp"):
            pass
    except OSError as exc:
        raise UserError(f"--cache-dir: cannot write in {folder}: {exc.strerror or exc}") from None


def _built(result: SceneCaches) -> str:
    """A variant's build in a progress line."""
    made = sum(use.built for use in result.entries)
    what = result.tissue or "no tissue: nothing to cache"
    return f"{what}; {made} built, {len(result.entries) - made} found ({result.seconds:.1f} s)"


def _run_caches(args: argparse.Namespace) -> int:
    from membrane_models.fem.cache import cache_directory
    from membrane_server.cache_build import build_scene_caches, missing_entries, variants

    executor = executor_from_args(args)
    root = args.cache_dir if args.cache_dir is not None else cache_directory().parent
    root = root.resolve()
    folder = cache_directory(root)
    built = variants(args.scene, args.vary)
    _require_writable(folder)
    jobs = [Job(v.label, build_scene_caches, (v, str(root))) for v in built]
    count = f"{len(jobs)} variant(s) of {len(args.scene)} scene(s)"
    print(f"membrane caches: {count} into {folder}", flush=True)
    results = executor.run(jobs, report=_built)
    missing = missing_entries(results, root)
    if missing:
        raise UserError(
            f"{len(missing)} entries were written where this machine cannot see them (not in "
            f"{folder}): give --cache-dir a directory every node of the cluster shares"
        )
    return 0
