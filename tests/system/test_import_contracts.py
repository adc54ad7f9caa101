"""The import contracts cover every package, and breaking one fails `lint-imports`.

`lint-imports` (run by `make test` and `make lint`) checks the contracts in pyproject.toml's
[tool.importlinter]; each of our import packages is the source of exactly one contract.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"


def _config() -> dict[str, Any]:
    with (ROOT / "pyproject.toml").open("rb") as f:
        config: dict[str, Any] = tomllib.load(f)["tool"]["importlinter"]
    return config


def _our_packages() -> set[str]:
    """Every import package of the distribution: <folder>/membrane_*/__init__.py."""
    return {path.parent.name for path in ROOT.glob("*/membrane_*/__init__.py")}


def test_every_package_is_a_root_and_the_source_of_one_contract() -> None:
    config = _config()
    assert set(config["root_packages"]) == _our_packages()
    sources = [module for c in config["contracts"] for module in c["source_modules"]]
    top_level = [module for module in sources if "." not in module]
    assert sorted(top_level) == sorted(_our_packages()), "one contract per package"
    inner = {module.split(".")[0] for module in sources if "." in module}
    assert inner <= _our_packages()  # contracts inside a package name real subpackages


def test_no_package_of_ours_is_left_out_of_the_wheel() -> None:
    with (ROOT / "pyproject.toml").open("rb") as f:
        wheel = tomllib.load(f)["tool"]["hatch"]["build"]["targets"]["wheel"]["packages"]
    assert {Path(entry).name for entry in wheel} == _our_packages()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("added", "contract", "chain"),
    [
        ("import torch", "server: never imports torch", "membrane_server.dispatch -> torch"),
        (
            "import membrane_models.learned.networks",
            "server: never imports torch, onnx, membrane_models.learned",
            "membrane_server.dispatch -> membrane_models.learned",
        ),
    ],
)
def test_a_broken_contract_fails_lint_imports_and_is_named(
    tmp_path: Path, added: str, contract: str, chain: str
) -> None:
    if not LINT_IMPORTS.exists():
        pytest.fail(f"lint-imports is not installed next to {sys.executable} (the dev extra)")
    for folder in {path.parent.parent for path in ROOT.glob("*/membrane_*/__init__.py")}:
        shutil.copytree(folder, tmp_path / folder.name, ignore=shutil.ignore_patterns("*.pyc"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    dispatch = tmp_path / "server" / "membrane_server" / "dispatch.py"
    dispatch.write_text(dispatch.read_text() + f"\n{added}  # noqa\n")
    paths = ":".join(str(p.parent.parent) for p in tmp_path.glob("*/membrane_*/__init__.py"))
    result = subprocess.run(
        [str(LINT_IMPORTS), "--no-cache"],
        cwd=tmp_path,
        env={"PYTHONPATH": paths, "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode != 0, result.stdout
    assert f"{contract}" in result.stdout and "BROKEN" in result.stdout
    assert chain in result.stdout
