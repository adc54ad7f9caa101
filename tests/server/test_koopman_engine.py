"""The ``koopman`` live engine on the built-in ``rope-koopman`` scene: a session opened with a
test-split shape steps it like the Galerkin reference; onnxruntime only, no torch."""

from __future__ import annotations

import numpy as np
import pytest

from membrane_client import Client, Load, ServerError
from membrane_models.data.koopman import DatasetSpec, initial_state
from membrane_models.exact.kirchhoff_carrier import KirchhoffString, sine_basis, solve_kirchhoff
from membrane_models.live import InvalidEngineSettings, InvalidShape
from membrane_models.problems import make_problem
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.koopman_engine import build_koopman_engine
from membrane_server.served import ServedScene

STEPS = 100


@pytest.fixture(scope="module")
def rope_koopman() -> ServedScene:
    return ServedScene.load("rope-koopman")


def _client(scene: ServedScene) -> Client:
    return Client("in-process://koopman", transport=InProcessTransport(Dispatcher([scene])))


def _test_shape(family: str, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A test-split trajectory's start (regenerated from its seed) on the 130-point lattice."""
    state = initial_state(DatasetSpec(), family, "test", index)
    lattice = np.arange(130) / 129
    basis = sine_basis(lattice, state.q0.size)
    return basis @ state.q0, basis @ state.p0, state.q0, state.p0


def test_a_session_opened_with_a_test_shape_follows_the_nonlinear_string(
    rope_koopman: ServedScene,
) -> None:
    u0, v0, q0, p0 = _test_shape("sine", 1)  # nonlinearity 0.39: the strong band
    reference = solve_kirchhoff(KirchhoffString(1.0, 100.0), q0, p0, [STEPS * 0.01])
    want = sine_basis(np.arange(130) / 129, q0.size) @ reference.q[0]
    with _client(rope_koopman) as client:
        info = client.describe("rope-koopman")
        assert info.live["engine"] == "koopman" and info.live["latent"] == 21
        assert info.live["eigenvalue_modulus_max"] <= 1.0 + 1e-6
        assert len(info.live["error_table"]) > 0
        with client.session("rope-koopman", initial={"displacement": u0, "velocity": v0}) as s:
            assert s.residuals["displacement"] < 0.1
            for _ in range(STEPS - 1):
                s.step(frame=False)
            frame = s.step()
            with pytest.raises(ServerError):
                s.step(loads=[Load((0.5,), 0.1, 0.05)])  # no loads: refused, nothing applied
    assert frame.k == STEPS and frame.z is not None and frame.z.shape == (130,)
    scale = np.linalg.norm(u0)  # at rest at t = 0: the motion's largest displacement
    error = np.linalg.norm(frame.z - want) / scale
    omega = np.pi * np.arange(1, q0.size + 1)
    turned = q0 * np.cos(omega * STEPS * 0.01) + p0 / omega * np.sin(omega * STEPS * 0.01)
    linear = sine_basis(np.arange(130) / 129, q0.size) @ turned  # the linear string, exact
    linear_error = np.linalg.norm(linear - want) / scale
    assert error < 0.1 and error < linear_error / 5


def test_the_engine_refuses_what_it_was_not_trained_for() -> None:
    problem = make_problem("string-kirchhoff")
    with pytest.raises(InvalidEngineSettings, match="nx = 130"):
        build_koopman_engine(problem, (100,), 0.01, {})
    with pytest.raises(InvalidEngineSettings, match="dt"):
        build_koopman_engine(problem, (130,), 0.001, {})
    with pytest.raises(InvalidEngineSettings, match="stretch"):
        build_koopman_engine(make_problem("string-kirchhoff", {"stretch": "10"}), (130,), 0.01, {})
    with pytest.raises(InvalidEngineSettings, match="unknown"):
        build_koopman_engine(problem, (130,), 0.01, {"damping": 0.1})
    engine = build_koopman_engine(problem, (130,), 0.01, {})
    x = np.arange(130) / 129
    with pytest.raises(InvalidShape, match="nonlinearity"):
        engine.start(0.2 * np.sin(np.pi * x))  # eps far beyond the training set's 1
