"""Numerical extremes: times at and beyond the domain's edges, tiny and huge steps, the smallest
and largest lattices, the exact solver over four decades of wave speed, and shipped models.

Every served value is checked against an independent computation (the evaluator called
directly, or the exact solution), not only for being finite.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import MAX_LATTICE_POINTS, Request, decode, unpack_array
from membrane_models.artifacts.zoo_index import list_models, resolve_model
from membrane_models.exact import exact_solution
from membrane_models.problems import make_problem
from membrane_server.runtime import load_graph
from membrane_server.scene import SceneError, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.server import Server
from membrane_server.timeline import OutOfDomain, Timeline

if TYPE_CHECKING:
    from onnx_graphs import TestModel

    from membrane_models.artifacts.manifest import Manifest

KINDS = ["network", "separable", "table", "exact"]
DT = 0.01
LAST = 100  # the fixture scenes: dt 0.01, duration 1 s


def _scene(**fields: Any) -> ServedScene:
    data: dict[str, Any] = {
        "name": "extreme", "model": "membrane-forced", "evaluator": "exact",
        "lattice": {"nx": 5, "ny": 5}, "dt": DT, "duration": 1.0,
    }  # fmt: skip
    data.update(fields)
    return ServedScene.load(scene_from_dict(data))


def _exact_at(problem: str, points: np.ndarray, t: float, **overrides: str) -> np.ndarray:
    solution = exact_solution(make_problem(problem, overrides))
    values: np.ndarray = solution.at_points(points, np.array([t]))[:, 0]
    return values


# -- times at the edges of the domain ---------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_t_zero_is_step_zero_and_the_initial_state(
    evaluator_scenes: dict[str, ServedScene], kind: str
) -> None:
    served = evaluator_scenes[kind]
    reply = served.query(0.0)
    assert (reply["step"], reply["t"], reply["domain"]) == (0, 0.0, "inside")
    z = unpack_array(reply["z"]).reshape(-1)
    # Zero initial condition: the exact solution is 0; the test graphs are t^2 B(t) + bias.
    expected = 0.0 if kind == "exact" else np.float32(1e-6)
    np.testing.assert_allclose(z, expected, rtol=1e-6, atol=0.0)


@pytest.mark.parametrize("kind", KINDS)
def test_the_last_step_is_inside_and_exact(
    evaluator_scenes: dict[str, ServedScene], kind: str
) -> None:
    served = evaluator_scenes[kind]
    reply = served.query(1.0)
    assert (reply["step"], reply["t"], reply["domain"]) == (LAST, 1.0, "inside")
    z = unpack_array(reply["z"]).reshape(-1)
    np.testing.assert_array_equal(z, served.evaluator.frame(LAST * DT).astype(np.float32))


@pytest.mark.parametrize(
    ("policy", "domain"), [("hold", "held"), ("clamp", "clamped"), ("error", None)]
)
def test_just_past_and_far_past_the_domain_follow_the_policy(
    policy: str, domain: str | None
) -> None:
    timeline = Timeline(dt=DT, last_step=LAST, policy=policy)  # type: ignore[arg-type]
    assert timeline.resolve(1.0 + 0.49 * DT).step == LAST  # rounds to the last step: inside
    # Half a step past the end rounds up to step N + 1 (1.005 / 0.01 is 100.4999... in binary,
    # so the test goes a hair beyond it).
    for t in (1.0 + 1e-9 + 0.5 * DT, 1.0 + 0.51 * DT, 2.0, 1e3, 1e9, 1e300, 1.7e308):
        if domain is None:
            with pytest.raises(OutOfDomain, match=r"outside the scene's time domain \[0.0, 1.0\]"):
                timeline.resolve(t)
            continue
        sample = timeline.resolve(t)
        assert (sample.step, sample.t, str(sample.domain)) == (LAST, 1.0, domain)
    for t in (-0.51 * DT, -1.0, -1e9, -1.7e308):
        if domain is None:
            with pytest.raises(OutOfDomain):
                timeline.resolve(t)
            continue
        sample = timeline.resolve(t)
        assert (sample.step, sample.t, str(sample.domain)) == (0, 0.0, domain)


def test_error_policy_on_the_wire(start_server: Callable[..., Server]) -> None:
    server = start_server([_scene(policy="error")])
    with Client(server.address, timeout=5.0) as client:
        assert client.query(1.0).step == LAST
        for t in (1.0 + 0.51 * DT, 1e9, -1e9, 1e308):
            with pytest.raises(ServerError) as caught:
                client.query(t)
            assert caught.value.code == "out_of_domain"
            assert "[0.0, 1.0]" in caught.value.message


def test_huge_and_tiny_times_travel_as_float64(evaluator_server: Server) -> None:
    """t = 1e9 and t = -1e-12 come back digit for digit; the step is computed in float64."""
    with Client(evaluator_server.address, timeout=5.0, scene="exact") as client:
        far = client.query(1e9)
        assert (far.requested_t, far.step, far.t, far.domain) == (1e9, LAST, 1.0, "held")
        before = client.query(-1e-12)
        assert (before.requested_t, before.step, before.t, before.domain) == (
            -1e-12, 0, 0.0, "inside"
        )  # fmt: skip
        odd = 0.1 + 0.2  # 0.30000000000000004: not a float32 number
        assert client.query(odd).requested_t == odd
        for t in (1.7976931348623157e308, -1.7976931348623157e308, 5e-324):
            assert math.isfinite(client.query(t).t)


def test_a_step_index_beyond_float32_precision() -> None:
    """10^9 steps of 1 ms: float32 cannot tell step 123456789 from 123456792."""
    served = _scene(dt=1e-3, duration=1e6, lattice={"points": [[0.8, 0.5]]}, policy="error")
    assert served.timeline.last_step == 10**9
    reply = served.query(123456.789)
    assert reply["step"] == 123_456_789
    assert np.float32(123456.789) / np.float32(1e-3) != 123_456_789  # the trap avoided
    assert reply["t"] == pytest.approx(123456.789, abs=1e-9)
    z = unpack_array(reply["z"])
    assert np.all(np.isfinite(z))  # free ringing long after the force: still finite


def test_a_huge_start_offset_keeps_the_step() -> None:
    """At simulation time 1e8 s float32 steps by 8 s; the served step must not care."""
    served = _scene(start_offset=1e8, lattice={"points": [[0.5, 0.5]]}, policy="error")
    reply = served.query(1e8 + 0.37)
    assert (reply["step"], reply["domain"]) == (37, "inside")
    np.testing.assert_allclose(
        unpack_array(reply["z"]), _exact_at("membrane-forced", np.array([[0.5, 0.5]]), 0.37),
        rtol=1e-6,
    )  # fmt: skip
    with pytest.raises(OutOfDomain):
        served.query(1e8 - 0.01)


# -- steps much smaller and much larger than the domain ------------------------------------------


def test_a_microsecond_step() -> None:
    """10^6 steps: frames too many to precompute, each computed on demand, each exact."""
    served = _scene(dt=1e-6, lattice={"nx": 20, "ny": 20})  # 3.2 GB of frames: over budget
    assert served.evaluator.info()["precomputed_frames"] == 0
    points = served.evaluator.points
    for t, step in ((0.5 + 3e-7, 500_000), (0.123456, 123_456), (1.0, 1_000_000)):
        reply = served.query(t)
        assert reply["step"] == step
        expected = _exact_at("membrane-forced", points, step * 1e-6)
        z = unpack_array(reply["z"]).reshape(-1)
        np.testing.assert_allclose(z, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


def test_a_step_longer_than_the_force() -> None:
    """dt = 10 s: one step past the 1 s force; the exact solution rings freely and stays finite."""
    served = _scene(dt=10.0, duration=10.0, lattice={"points": [[0.3, 0.4]]})
    reply = served.query(7.0)  # nearer step 1 (10 s) than step 0
    assert (reply["step"], reply["t"]) == (1, 10.0)
    expected = _exact_at("membrane-forced", np.array([[0.3, 0.4]]), 10.0)
    z = unpack_array(reply["z"]).astype(np.float64)
    assert 0 < abs(expected[0]) < 1e-3
    np.testing.assert_allclose(z, expected, rtol=1e-6)


def test_a_network_refuses_steps_beyond_its_trained_domain(
    test_models: dict[str, TestModel],
) -> None:
    model = str(test_models["membrane"].manifest_path)
    with pytest.raises(SceneError, match="reaches past the model's time domain"):
        _scene(model=model, evaluator="separable", dt=10.0, duration=10.0)


def test_a_step_longer_than_the_duration_is_refused() -> None:
    with pytest.raises(SceneError, match=r"duration: must be a whole number \(>= 1\) of dt"):
        scene_from_dict(
            {"name": "x", "model": "membrane-forced", "evaluator": "exact",
             "lattice": {"nx": 2, "ny": 2}, "dt": 10.0, "duration": 1.0}
        )  # fmt: skip


# -- lattice sizes ----------------------------------------------------------------------------


def test_a_one_point_lattice() -> None:
    corner = _scene(lattice={"nx": 1, "ny": 1})  # linspace(0, 1, 1): the corner, fixed at 0
    reply = corner.query(0.5)
    assert unpack_array(reply["z"]).shape == (1, 1)
    assert unpack_array(reply["z"])[0, 0] == 0.0
    under_the_force = _scene(lattice={"points": [[0.8, 0.5]]})
    z = unpack_array(under_the_force.query(0.5, "<f8")["z"])
    expected = _exact_at("membrane-forced", np.array([[0.8, 0.5]]), 0.5)
    assert z.shape == (1,) and abs(expected[0]) > 1e-4
    np.testing.assert_allclose(z, expected, rtol=1e-12)


def test_the_largest_2d_lattice_end_to_end(
    test_models: dict[str, TestModel], start_server: Callable[..., Server]
) -> None:
    """256 x 256 = 65,536 points, through the wire; separable against the full network."""
    model = str(test_models["membrane"].manifest_path)
    lattice = {"nx": 256, "ny": 256}
    separable = _scene(name="separable", model=model, evaluator="separable", lattice=lattice)
    network = _scene(name="network", model=model, evaluator="network", lattice=lattice)
    assert separable.evaluator.n_points == MAX_LATTICE_POINTS
    server = start_server([separable, network])
    with Client(server.address, timeout=10.0) as client:
        fast = client.query(0.5, "separable", dtype="<f8").z
        full = client.query(0.5, "network").z
    assert fast.shape == full.shape == (256, 256)
    assert np.all(np.isfinite(fast))
    scale = np.linalg.norm(full)
    assert scale > 0 and np.linalg.norm(fast - full) / scale < 1e-5


def test_the_largest_1d_lattice_against_the_exact_solution() -> None:
    served = _scene(model="string-forced", lattice={"nx": MAX_LATTICE_POINTS}, table_max_bytes=1)
    reply = served.query(0.5, "<f8")
    z = unpack_array(reply["z"])
    assert z.shape == (MAX_LATTICE_POINTS,)
    x = np.linspace(0.0, 1.0, MAX_LATTICE_POINTS)[::4096, None]
    np.testing.assert_allclose(z[::4096], _exact_at("string-forced", x, 0.5), rtol=1e-12)
    assert max(abs(z[0]), abs(z[-1])) <= 1e-12 * np.abs(z).max()  # fixed ends


# -- the exact solver over wave speeds and force positions ---------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("problem", ["string-forced", "membrane-forced"])
@pytest.mark.parametrize("c", ["0.1", "1", "10", "100"])
def test_exact_solver_states_an_honest_truncation_error(problem: str, c: str) -> None:
    """The series at rtol 1e-6 differs from one at rtol 1e-10 by no more than it says."""
    coarse = exact_solution(make_problem(problem, {"C": c}), rtol=1e-6)
    fine = exact_solution(make_problem(problem, {"C": c}), rtol=1e-10)
    axes = [np.linspace(0.0, 1.0, 17)] * coarse.spatial_dims + [np.linspace(0.0, 1.0, 41)]
    u_coarse, u_fine = coarse.grid(*axes), fine.grid(*axes)
    assert np.all(np.isfinite(u_coarse)) and np.all(np.isfinite(u_fine))
    scale = float(np.abs(u_fine).max())
    assert scale > 0
    actual = float(np.abs(u_coarse - u_fine).max()) / scale
    assert 0 < coarse.truncation_error <= 1e-6
    # The stated bound is relative to the largest |u| on the solver's own sampling grid, which
    # can sit a little below this grid's maximum; allow the fine series' own error on top.
    assert actual <= 1.05 * coarse.truncation_error + fine.truncation_error


@pytest.mark.slow
@pytest.mark.parametrize(
    ("problem", "overrides"),
    [
        ("string-forced", {"x0": "0.995"}),
        ("string-forced", {"x0": "0.005", "C": "100"}),
        ("membrane-forced", {"x0": "0.98", "y0": "0.02"}),
        ("membrane-forced", {"x0": "0.5", "y0": "0.99", "C": "0.1"}),
    ],
)
def test_forces_near_the_boundary_stay_finite_with_a_stated_error(
    problem: str, overrides: dict[str, str], caplog: pytest.LogCaptureFixture
) -> None:
    """A force near an edge has a slowly decaying spectrum: the series may hit its memory limits
    before rtol; then the error it reaches is stated and logged, never hidden."""
    rtol = 1e-6
    with caplog.at_level(logging.WARNING, logger="membrane_models.exact.forced"):
        solution = exact_solution(make_problem(problem, overrides), rtol=rtol)
    axes = [np.linspace(0.0, 1.0, 33)] * solution.spatial_dims + [np.linspace(0.0, 1.5, 31)]
    u = solution.grid(*axes)
    peak = float(np.abs(u).max())
    assert np.all(np.isfinite(u)) and peak > 0
    assert math.isfinite(solution.truncation_error) and solution.truncation_error > 0
    if solution.truncation_error > rtol:
        assert f"truncation error {solution.truncation_error:.2g} exceeds rtol" in caplog.text
    for edge in (u[0], u[-1]):  # x = 0 and x = 1 stay fixed (sin(m pi) is 0 to rounding)
        assert float(np.abs(edge).max()) <= 1e-12 * peak


# -- trained models: finite over their whole domain ----------------------------------------------


def _check_model_over_its_domain(manifest: Manifest) -> float:
    """Run the full graph (sha256-checked) over a grid of its space-time domain; returns max |u|.

    Also compares the magnitude with the exact solution's on the same grid: a network whose
    output is orders of magnitude off is answering nonsense, finite or not.
    """
    runner = load_graph(manifest, "full")
    bounds = [bounds for axis, bounds in manifest.domain.items() if axis != "t"]
    space = [np.linspace(low, high, 21) for low, high in bounds]
    t_low, t_high = manifest.domain["t"]
    times = np.linspace(t_low, t_high, 51)
    grids = np.meshgrid(*space, times, indexing="ij")
    inputs = np.stack([g.reshape(-1) for g in grids], axis=1)
    u = runner.run(inputs.astype(np.float32)).reshape(-1)
    assert u.shape == (inputs.shape[0],)
    assert np.all(np.isfinite(u)), f"{manifest.name}: non-finite outputs"
    problem = make_problem(manifest.problem, {k: str(v) for k, v in manifest.parameters.items()})
    reference = exact_solution(problem, rtol=1e-6).grid(*space, times).reshape(-1)
    peak = float(np.abs(u).max())
    assert peak <= 10 * float(np.abs(reference).max()), f"{manifest.name}: max |u| = {peak:.3g}"
    return peak


def test_the_test_models_are_finite_over_their_domain(test_models: dict[str, TestModel]) -> None:
    """The same check as for the zoo, on models that always exist (untrained, amplitude 1e-3)."""
    for name in ("membrane", "string", "membrane_full_only"):
        manifest = resolve_model(test_models[name].manifest_path)
        assert _check_model_over_its_domain(manifest) > 0


@pytest.mark.parametrize("name", list_models() or ["<none>"])
def test_every_shipped_model_is_finite_over_its_domain(name: str) -> None:
    if name == "<none>":
        pytest.skip("the zoo ships no model yet (models/membrane_models/zoo has no manifest)")
    assert _check_model_over_its_domain(resolve_model(name)) > 0


def test_a_raw_query_for_the_last_representable_time(evaluator_server: Server) -> None:
    """The largest float64 goes through msgpack and the server untouched."""
    import zmq

    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.REQ)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, 5000)
    socket.connect(evaluator_server.address)
    try:
        socket.send(Request("query", 7, scene="table", t=1.7976931348623157e308).to_wire())
        reply = decode(socket.recv())
    finally:
        socket.close(linger=0)
    assert (reply["ok"], reply["step"], reply["domain"]) == (True, LAST, "held")
    assert reply["requested_t"] == 1.7976931348623157e308
