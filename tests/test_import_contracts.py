"""The import contracts' module groups stay complete and consistent.

`lint-imports` (run by `make test` and `make lint`) checks the contracts in pyproject.toml's
[tool.importlinter]. The load tester (membrane_bench) and the CoppeliaSim adapter
(membrane_coppelia) are packages of their own, named whole in every contract; the client contract
lists the client's own modules one by one. These tests keep the lists honest: a new module in
membrane_client must join the client's list, and a group is never named in part.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
CLIENT_DIR = ROOT / "client" / "membrane_client"
GROUPS = ("client", "bench", "coppelia")  # contract ids whose source modules define a group
CLIENT_GROUPS = ("client",)  # the groups made of membrane_client's own modules


def _contracts() -> dict[str, dict[str, Any]]:
    with (ROOT / "pyproject.toml").open("rb") as f:
        config = tomllib.load(f)["tool"]["importlinter"]
    return {contract["id"]: contract for contract in config["contracts"]}


def _group(contract_id: str) -> set[str]:
    return set(_contracts()[contract_id]["source_modules"])


def _client_modules() -> set[str]:
    names = set()
    for path in CLIENT_DIR.rglob("*.py"):
        parts = path.relative_to(CLIENT_DIR.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names.add(".".join(parts))
    return names


def test_every_client_module_is_in_exactly_one_group() -> None:
    placed: dict[str, list[str]] = {}
    for group in CLIENT_GROUPS:
        for module in _group(group):
            placed.setdefault(module, []).append(group)
    twice = {module: groups for module, groups in placed.items() if len(groups) > 1}
    assert not twice, f"modules in more than one group: {twice}"
    missing = _client_modules() - placed.keys()
    assert not missing, f"client modules in no import-contract group (pyproject.toml): {missing}"
    gone = placed.keys() - _client_modules()
    assert not gone, f"import-contract groups name modules that do not exist: {gone}"


def test_a_group_is_named_whole_or_not_at_all() -> None:
    for group in ("bench", "coppelia"):
        members = _group(group)
        for contract_id, contract in _contracts().items():
            for field in ("source_modules", "forbidden_modules"):
                named = members & set(contract[field])
                assert not named or named == members, (
                    f"contract {contract_id!r} {field} names part of the {group} group: "
                    f"missing {sorted(members - named)}"
                )


def test_the_other_groups_are_forbidden_to_each_group() -> None:
    contracts = _contracts()
    for contract_id in GROUPS:
        forbidden = set(contracts[contract_id]["forbidden_modules"])
        for other in ("bench", "coppelia"):
            if other != contract_id:
                assert _group(other) <= forbidden, f"{contract_id!r} may import {other}"
    server_forbidden = set(contracts["server"]["forbidden_modules"])
    assert _group("bench") | _group("coppelia") <= server_forbidden
