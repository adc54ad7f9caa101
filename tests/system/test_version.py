"""One version everywhere: `membrane --version`, a server's `hello`, CHANGELOG.md and pyproject.

`membrane --version` and the ``server`` field of ``hello`` both read the installed distribution's
metadata; the changelog's top released entry (the first after Unreleased) must name the same
version, and so must pyproject.toml (a stale editable install reads an older one: reinstall with
``pip install -e '.[dev]'``). The wheel names the README and the docs give follow it too.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from membrane_client import Client
from membrane_server.server import Server

ROOT = Path(__file__).resolve().parents[2]
CHANGELOG = ROOT / "CHANGELOG.md"
RELEASE_HEADING = re.compile(r"^## \[(?P<version>[^\]]+)\](?: - (?P<date>\S+))?\s*$")
WHEEL_NAME = re.compile(r"membrane_tissue-(\d+\.\d+\.\d+)-py3-none-any\.whl")


def changelog_releases(text: str) -> list[tuple[str, str | None]]:
    """The changelog's release headings, top first: (version or 'Unreleased', date)."""
    return [
        (match["version"], match["date"])
        for line in text.splitlines()
        if (match := RELEASE_HEADING.match(line))
    ]


def top_released_version(text: str) -> str:
    released = [version for version, _ in changelog_releases(text) if version != "Unreleased"]
    assert released, "CHANGELOG.md has no released entry"
    return released[0]


def test_changelog_parsing_finds_the_first_release_below_unreleased() -> None:
    text = "# Changelog\n\n## [Unreleased]\n\n- x\n\n## [1.2.0] - 2030-01-01\n\n## [1.1.0]\n"
    assert top_released_version(text) == "1.2.0"
    assert changelog_releases(text)[0] == ("Unreleased", None)


def test_changelog_keeps_an_unreleased_section_then_dated_releases_newest_first() -> None:
    releases = changelog_releases(CHANGELOG.read_text())
    assert releases[0] == ("Unreleased", None), releases
    versions = [tuple(int(part) for part in version.split(".")) for version, _ in releases[1:]]
    assert versions and versions == sorted(versions, reverse=True), releases
    assert all(re.fullmatch(r"\d{4}-\d\d-\d\d", date or "") for _, date in releases[1:]), releases
    assert releases[-1][0] == "0.1.0"


@pytest.mark.slow
def test_version_flag_hello_and_changelog_agree(membrane_server: Server) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "membrane_cli", "--version"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    cli_version = result.stdout.strip()

    with Client(membrane_server.address, timeout=5.0) as client:
        server_version = client.hello().server

    released = top_released_version(CHANGELOG.read_text())
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert cli_version == server_version == f"membrane {released}", (
        cli_version,
        server_version,
        released,
    )
    assert project == released, f"pyproject.toml says {project}, CHANGELOG.md {released}"


def test_wheel_names_in_the_readme_and_docs_carry_the_version() -> None:
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    stale = [
        f"{path.relative_to(ROOT)}: {match.group(0)}"
        for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
        for match in WHEEL_NAME.finditer(path.read_text())
        if match.group(1) != version
    ]
    assert not stale, f"wheel names not at version {version}: {stale}"
