"""A new live engine kind is one module plus one entry point: no change to the server.

A small package made here (a module and its dist-info, found on PYTHONPATH as any installed
distribution is) registers an engine that answers zeros under ``membrane.engines``; a real
`membrane serve` hosts a scene whose ``[live]`` table names it, and a real ``Session`` steps it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import ErrorCode
from membrane_server.engines import ENGINE_GROUP

pytestmark = pytest.mark.slow

MEMBRANE = [sys.executable, "-m", "membrane_cli"]

ZEROS_ENGINE = '''
"""An engine that answers zeros: the smallest thing the LiveEngine interface allows."""
from dataclasses import dataclass
import numpy as np
from membrane_models.live import ProbeReading, Start, StepResult


@dataclass(frozen=True)
class State:
    step: int


class Zeros:
    spatial_dims = 1
    inputs = frozenset({"probes"})
    state_bytes = 64

    def __init__(self, problem, lattice, dt, options):
        self.lattice_shape, self.dt, self.level = lattice, dt, float(options.get("level", 0.0))

    def start(self, displacement=None, velocity=None):
        return Start(State(0), 0.0, 0.0)

    def step(self, state, loads=(), probes=(), *, frame=True):
        readings = tuple(ProbeReading(0.0, 0.0, 0.0, 0.0, False) for _ in probes)
        new = State(state.step + 1)
        return StepResult(new, self.frame(new) if frame else None, readings, None)

    def frame(self, state):
        return np.full(int(np.prod(self.lattice_shape)), self.level)

    def describe(self):
        return {"engine": "zeros", "inputs": sorted(self.inputs), "level": self.level}
'''


def _package(root: Path) -> Path:
    (root / "zeros_engine.py").write_text(ZEROS_ENGINE)
    info = root / "zeros_engine-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: zeros-engine\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[membrane.engines]\nzeros = zeros_engine:Zeros\n")
    return root


def _scene(root: Path, engine: str) -> Path:
    path = root / f"{engine}.toml"
    path.write_text(
        textwrap.dedent(f"""
        name = "{engine}-rope"
        model = "string-forced"
        evaluator = "exact"
        dt = 0.001
        duration = 1.0
        [lattice]
        nx = 11
        [live]
        engine = "{engine}"
        level = 0.0
    """)
    )
    return path


def _serve(scene: Path, package: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": f"{package}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", str(scene), "--bind", "tcp://127.0.0.1:*"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip


def test_an_engine_registered_by_another_package_is_served_through_a_real_session(
    tmp_path: Path,
) -> None:
    package = _package(tmp_path)
    server = _serve(_scene(tmp_path, "zeros"), package)
    try:
        assert server.stdout is not None
        line = server.stdout.readline()  # "membrane serve: listening on ADDRESS (scenes: ...)"
        address = line.split("listening on ")[-1].split()[0]
        assert address.startswith("tcp://127.0.0.1:"), line
        with Client(address, timeout=5.0) as client:
            live = client.describe("zeros-rope").live
            assert live["engine"] == "zeros" and live["inputs"] == ["probes"]
            assert live["session_bytes"] > 0
            with client.session("zeros-rope") as session:
                frame = session.step(probes=[{"at": [0.5], "depth": 0.001, "radius": 0.05}])
                assert frame.k == 1 and frame.z is not None
                assert np.array_equal(frame.z, np.zeros(11, np.float32))
                with pytest.raises(ServerError) as refused:  # it declared no loads
                    session.step(loads=[{"at": [0.5], "force": 1.0, "radius": 0.05}])
                assert refused.value.code == ErrorCode.BAD_REQUEST
                assert "takes no loads" in refused.value.message
    finally:
        server.terminate()
        server.wait(10)


def test_an_unregistered_engine_kind_is_refused_at_load_in_one_line(tmp_path: Path) -> None:
    server = _serve(_scene(tmp_path, "nowhere"), tmp_path)
    _, stderr = server.communicate(timeout=60)
    assert server.returncode == 2, stderr
    errors = [line for line in stderr.splitlines() if "error:" in line]
    registered = ", ".join(sorted(entry.name for entry in entry_points(group=ENGINE_GROUP)))
    assert len(errors) == 1 and errors[0].endswith(
        f"[live] engine 'nowhere' is not registered; registered: {registered}"
    ), stderr
    assert "Traceback" not in stderr
