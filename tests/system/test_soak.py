"""The soak benchmark (benchmarks/soak.py), run briefly so that it keeps working.

The real run (1 kHz from 4 clients for 60 s) is in docs/ROBUSTNESS.md; here 3 s at 200 Hz.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SOAK = Path(__file__).resolve().parents[2] / "benchmarks" / "soak.py"


def test_a_short_soak_passes_and_reports_its_figures(tmp_path: Path) -> None:
    output = tmp_path / "soak.json"
    result = subprocess.run(
        [sys.executable, str(SOAK), "--rate", "200", "--clients", "2", "--duration", "3",
         "--settle", "1", "--json", str(output)],
        capture_output=True,
        text=True,
        timeout=180,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    figures = json.loads(output.read_text())
    assert figures["failed"] == []
    assert figures["sent"] == figures["replies"] == figures["ok"] >= 500
    assert figures["errors"] == {} and figures["server_errors"] == {}
    assert figures["server_requests"] >= figures["sent"]
    rss = figures["rss_kib"]
    assert len(rss["samples"]) >= 4 and rss["start"] > 0 and rss["end"] > 0
    assert abs(figures["rss_growth"]) <= 0.05
    assert figures["server_exit_code"] == 0
    assert "| verdict | pass |" in result.stdout
