"""examples/poke.py against real `membrane serve` processes: on the physical skin patch (mm
and N) its held force is the plate's point stiffness, and on membrane-live (problem units) it
prints what it printed before, plus the force history's extremes."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from attackers import WatchedServer

POKE = Path(__file__).resolve().parents[2] / "examples" / "poke.py"
# The skin patch's point compliance at its centre (a 50 mm clamped Kirchhoff plate, D = 4.232e-3
# N m: docs/FEM.md's closed form and FEM agree), mm per N.
CENTRE_COMPLIANCE_MM_PER_N = 3.315
HELD = re.compile(r"^held at depth (\S+) (mm|problem units): force (\S+) ")


def _poke(address: str, tmp_path: Path, *arguments: str) -> str:
    plot = str(tmp_path / "poke.png")
    result = subprocess.run(
        [sys.executable, str(POKE), "--connect", address, "--plot", plot, *arguments],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def _held(out: str) -> tuple[float, str, float]:
    """(depth, its unit, force) from the 'held at depth' line."""
    found = [HELD.match(line) for line in out.splitlines()]
    matches = [m for m in found if m is not None]
    assert len(matches) == 1, out
    depth, unit, force = matches[0].groups()
    return float(depth), unit, float(force)


@pytest.fixture
def server(request: pytest.FixtureRequest) -> Iterator[WatchedServer]:
    """`membrane serve --scene NAME` on 127.0.0.1, a random port (the parameter names it)."""
    watched = WatchedServer([request.param])
    yield watched
    watched.close()


@pytest.mark.slow
@pytest.mark.parametrize("server", ["skin-patch"], indirect=True)
def test_poke_on_the_skin_patch_feels_the_plates_point_stiffness(
    server: WatchedServer, tmp_path: Path
) -> None:
    out = _poke(server.address, tmp_path, "--scene", "skin-patch")
    assert "probe at (25, 25) mm, radius 0 mm" in out  # the middle of the extent, a point
    depth, unit, force = _held(out)
    assert (depth, unit) == (0.5, "mm")
    expected = depth / CENTRE_COMPLIANCE_MM_PER_N  # N
    assert force == pytest.approx(expected, rel=0.02), out
    # The extremes of every step, the press's first ones one by one.
    assert re.search(r"^force history \(800 steps\): max \S+ N at t = ", out, re.M)
    assert re.search(r"^largest step-to-step jump: [-+]\S+ N into t = ", out, re.M)
    first = re.search(r"^force at the press's first 5 steps \(N\): (.+)$", out, re.M)
    assert first is not None and len(first.group(1).split(", ")) == 5


@pytest.mark.slow
@pytest.mark.parametrize("server", ["membrane-live"], indirect=True)
def test_poke_on_membrane_live_keeps_its_problem_units(
    server: WatchedServer, tmp_path: Path
) -> None:
    """The dimensionless path as before: radius 0.05 at (0.5, 0.5), depth 0.001, the README's
    stiffness and ringing (to 1 %: the figures, not the digits, are what must stay)."""
    out = _poke(server.address, tmp_path)
    assert "probe at (0.5, 0.5) problem units, radius 0.05 problem units" in out
    assert _held(out)[:2] == (0.001, "problem units")
    stiffness = re.search(r"^stiffness at full depth: (\S+) force per unit depth$", out, re.M)
    assert stiffness is not None and float(stiffness.group(1)) == pytest.approx(67.47, rel=0.01)
    held = re.search(r"mean (\S+) problem units over the hold's second half$", out, re.M)
    assert held is not None and float(held.group(1)) == pytest.approx(0.0686, rel=0.01)
    period = re.search(r"^ringing period (\S+) ms", out, re.M)
    assert period is not None and float(period.group(1)) == pytest.approx(306.0, rel=0.01)
    assert "released: the centre rings (damping 2 %)" in out
    assert re.search(r"^force at the press's first 5 steps \(problem units\): ", out, re.M)
