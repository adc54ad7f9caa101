"""Short training runs: the loss falls, runs are deterministic, checkpoints resume."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from membrane_models.exact import exact_solution
from membrane_models.problems import StringPlucked, make_problem
from membrane_models.training import (
    Collocation,
    TrainConfig,
    _strong_modal_residual,
    _weak_modal_residual,
    load_checkpoint,
    model_from_checkpoint,
    recipe,
    train,
)
from membrane_models.transforms import initial_shape_jet

TINY_SPINN: dict[str, Any] = {
    "name": "spinn", "rank": 6, "width": 16, "depth": 2,
    "space_features": {"kind": "harmonic", "features": 4, "include_input": True},
    "time_features": {"kind": "harmonic", "features": 4, "include_input": True},
}


def _tiny(problem: str, **changes: Any) -> TrainConfig:
    base: dict[str, Any] = {
        "arch": TINY_SPINN, "iterations": 60, "lbfgs_fraction": 0.25, "lr": 3e-3,
        "space_points": 16, "time_points": 16, "lbfgs_space_points": 20,
        "lbfgs_time_points": 20, "checkpoint_every": 20,
    }
    base.update(changes)
    return recipe(problem, **base)


@pytest.mark.parametrize("problem", ["string-forced", "membrane-forced", "string-plucked-smooth"])
def test_short_run_loss_falls(problem: str) -> None:
    result = train(_tiny(problem), progress=False)
    losses = [h["residual"] for h in result.history]
    assert len(losses) == 60
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def test_published_configuration_trains_with_initial_terms() -> None:
    config = recipe(
        "string-forced", "stmsffn", iterations=30,
        arch={"name": "stmsffn", "width": 16, "hidden": 2, "sigmas_x": [1.0],
              "sigmas_t": [1.0, 50.0], "shared": True},
        space_points=64, initial_points=32,
    )
    result = train(config, progress=False)
    first, last = result.history[0], result.history[-1]
    assert {"residual", "initial", "velocity"} <= set(last)
    assert last["residual"] + last["initial"] + last["velocity"] < (
        first["residual"] + first["initial"] + first["velocity"]
    )


def test_runs_are_deterministic_for_a_seed() -> None:
    a = train(_tiny("string-forced", iterations=20), progress=False).history
    b = train(_tiny("string-forced", iterations=20), progress=False).history
    c = train(_tiny("string-forced", iterations=20, seed=1), progress=False).history
    assert [h["residual"] for h in a] == [h["residual"] for h in b]
    assert [h["residual"] for h in a] != [h["residual"] for h in c]


def test_checkpoint_is_plain_data_and_resumes(tmp_path: Path) -> None:
    config = _tiny("string-forced", iterations=40, lbfgs_fraction=0.0)
    full = train(config, progress=False)
    train(config, out_dir=tmp_path, command="membrane train x", progress=False, until=20)
    data = load_checkpoint(tmp_path / "checkpoint.pt")  # weights_only=True inside
    assert data["iteration"] == 20 and data["command"] == "membrane train x"
    resumed = train(config, out_dir=tmp_path, resume=True, progress=False)
    assert resumed.iterations == 40
    assert [h["residual"] for h in resumed.history] == [h["residual"] for h in full.history]
    model, restored = model_from_checkpoint(load_checkpoint(tmp_path / "checkpoint.pt"))
    assert restored == config
    x = torch.rand(5, 2, dtype=torch.float64)
    torch.testing.assert_close(model(x), resumed.model(x))


def test_resume_refuses_another_configuration(tmp_path: Path) -> None:
    train(_tiny("string-forced", iterations=5), out_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        train(_tiny("string-forced", iterations=5, seed=3), out_dir=tmp_path, resume=True,
              progress=False)


def test_not_a_checkpoint_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "checkpoint.pt"
    bad.write_text("not a checkpoint")
    with pytest.raises(ValueError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")


@pytest.mark.parametrize("smoothing", ["0", "0.02"])
def test_initial_shape_matches_the_exact_solution_at_t0(smoothing: str) -> None:
    problem = make_problem("string-plucked", {"smoothing": smoothing})
    assert isinstance(problem, StringPlucked)
    x = np.linspace(0.0, 1.0, 201)
    expected = exact_solution(problem).grid(x, np.array([0.0]))[:, 0]
    got = initial_shape_jet(problem, torch.from_numpy(x)[:, None])[0][:, 0].numpy()
    np.testing.assert_allclose(got, expected, atol=1e-9 * problem.height)


def _midpoint_collocation(n_x: int, n_t: int, forcing: torch.Tensor | None = None) -> Collocation:
    x = (torch.arange(n_x, dtype=torch.float64) + 0.5) / n_x
    t = ((torch.arange(n_t, dtype=torch.float64) + 0.5) / n_t)[:, None]
    return Collocation([x], t, forcing=torch.zeros(n_x, n_t, dtype=torch.float64)
                       if forcing is None else forcing)


def test_weak_modal_residual_sees_the_kink_that_points_cannot() -> None:
    # u = the triangle, at rest: at every point u_tt = c^2 u_xx = 0, yet the kink's w'' is a
    # Dirac. The weak form must give -c^2 times its sine coefficients, 2 w''_n with
    # int w'' sin(n pi x) = -(h / x0 + h / (1 - x0)) sin(n pi x0); the strong form sees nothing.
    problem = make_problem("string-plucked")
    assert isinstance(problem, StringPlucked)
    points = _midpoint_collocation(4000, 3)
    x = points.space[0].numpy()
    u = torch.from_numpy(np.repeat(problem.triangle(x)[:, None], 3, axis=1))
    still = torch.zeros_like(u)
    weak, wavenumber = _weak_modal_residual(u, still, still, points, problem.c**2, 5)
    strong, _ = _strong_modal_residual(u, still, still, points, problem.c**2, 5)
    n = np.arange(1, 6)
    dirac = -(problem.height / problem.x0 + problem.height / (1.0 - problem.x0))
    expected = -(problem.c**2) * 2.0 * dirac * np.sin(np.pi * n * problem.x0)
    np.testing.assert_allclose(weak[:, 0].numpy(), expected, rtol=1e-5)
    np.testing.assert_allclose(wavenumber.numpy(), n)
    assert float(strong.abs().max()) == 0.0


def test_weak_and_strong_modal_residuals_agree_on_a_smooth_field() -> None:
    # u = x (1 - x) e^x t^2 (zero on the ends), f = 1: both forms project the same residual.
    c2, n_x = 4.0, 2000
    points = _midpoint_collocation(n_x, 4, forcing=torch.ones(n_x, 4, dtype=torch.float64))
    x, t = points.space[0][:, None], points.time[:, 0][None, :]
    shape = x * (1 - x) * torch.exp(x)
    shape_xx = -(x * x + 3 * x) * torch.exp(x)  # d2/dx2 of (x - x^2) e^x
    u, u_tt = shape * t**2, shape * 2 + 0 * t
    residual = u_tt - c2 * shape_xx * t**2 - 1.0
    weak, _ = _weak_modal_residual(u, u_tt, residual, points, c2, 6)
    strong, _ = _strong_modal_residual(u, u_tt, residual, points, c2, 6)
    np.testing.assert_allclose(weak.numpy(), strong.numpy(), rtol=1e-4, atol=1e-6)
    assert float(weak.abs().max()) > 0.1
