"""examples/press_tool.py against real `membrane serve` processes: a sphere pressed into
membrane-live and into the skin patch, float64 frames, the tissue nowhere above the tool by more
than 1e-6 of the depth (measured: 5e-16 and 2e-16 of it)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from attackers import WatchedServer

PRESS = Path(__file__).resolve().parents[2] / "examples" / "press_tool.py"
LARGEST = re.compile(r"^largest penetration over the lattice: (\S+) \(of the depth: (\S+)\)$")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "kind"),
    [("membrane-live", "sphere"), ("membrane-live", "cylinder"), ("skin-patch", "sphere")],
)
def test_a_pressed_tool_has_no_tissue_above_it(scene: str, kind: str) -> None:
    server = WatchedServer([scene])
    command = [sys.executable, str(PRESS), "--connect", server.address, "--scene", scene]
    try:
        result = subprocess.run(
            [*command, "--kind", kind],
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        server.close()
    assert result.returncode == 0, result.stdout + result.stderr
    found = [m for m in map(LARGEST.match, result.stdout.splitlines()) if m]
    assert len(found) == 1, result.stdout
    assert 0.0 <= float(found[0].group(2)) <= 1e-6
    assert " points in contact" in result.stdout and "force 0 " not in result.stdout
