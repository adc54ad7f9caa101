"""Printing a line of figures at the end of a test module, past pytest's output capture."""

from __future__ import annotations

import pytest


def print_past_capture(request: pytest.FixtureRequest, line: str) -> None:
    """Write ``line`` to the terminal report (nothing when pytest runs without one)."""
    reporter = request.config.pluginmanager.getplugin("terminalreporter")
    capture = request.config.pluginmanager.getplugin("capturemanager")
    if reporter is None or capture is None:
        return
    with capture.global_and_fixture_disabled():
        reporter.write_line(line)
