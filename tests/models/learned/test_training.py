"""Short training runs: the loss falls, runs are deterministic, checkpoints resume."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from membrane_errors import UserError
from membrane_models.exact import exact_solution
from membrane_models.learned.architectures import HarmonicFeatures, SpinnConfig, StmsffnConfig
from membrane_models.learned.training import (
    TrainConfig,
    build_model,
    load_checkpoint,
    model_from_checkpoint,
    recipe,
    train,
)
from membrane_models.learned.training.losses import (
    kink_coefficients,
    kink_series,
    sine_coefficients,
)
from membrane_models.learned.transforms import initial_shape_jet
from membrane_models.problems import StringPlucked, make_problem

TINY_SPINN = SpinnConfig(
    rank=6,
    width=16,
    depth=2,
    space_features=HarmonicFeatures(4),
    time_features=HarmonicFeatures(4),
)


def _tiny(problem: str, **changes: Any) -> TrainConfig:
    base: dict[str, Any] = {
        "arch": TINY_SPINN,
        "iterations": 60,
        "lbfgs_fraction": 0.25,
        "lr": 3e-3,
        "space_points": 16,
        "time_points": 16,
        "lbfgs_space_points": 20,
        "lbfgs_time_points": 20,
        "checkpoint_every": 20,
    }
    base.update(changes)
    return recipe(problem, **base)


@pytest.mark.slow
@pytest.mark.parametrize(
    "problem", ["string-forced", "membrane-forced", "string-plucked", "string-plucked-smooth"]
)
def test_short_run_loss_falls(problem: str) -> None:
    # The loss the optimiser minimises: the sum of its terms.
    result = train(_tiny(problem), progress=False)
    bookkeeping = ("iteration", "wall_time")
    terms = [{k: v for k, v in h.items() if k not in bookkeeping} for h in result.history]
    assert {"residual", "modal"} <= set(terms[-1])
    losses = [sum(t.values()) for t in terms]
    assert len(losses) == 60
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


@pytest.mark.slow
def test_published_configuration_trains_with_initial_terms() -> None:
    config = recipe(
        "string-forced",
        "stmsffn",
        iterations=30,
        arch=StmsffnConfig(width=16, hidden=2, sigmas_x=(1.0,), sigmas_t=(1.0, 50.0)),
        space_points=64,
        initial_points=32,
    )
    result = train(config, progress=False)
    first, last = result.history[0], result.history[-1]
    assert {"residual", "initial", "velocity"} <= set(last)
    assert last["residual"] + last["initial"] + last["velocity"] < (
        first["residual"] + first["initial"] + first["velocity"]
    )


@pytest.mark.slow
def test_runs_are_deterministic_for_a_seed() -> None:
    a = train(_tiny("string-forced", iterations=20), progress=False).history
    b = train(_tiny("string-forced", iterations=20), progress=False).history
    c = train(_tiny("string-forced", iterations=20, seed=1), progress=False).history
    assert [h["residual"] for h in a] == [h["residual"] for h in b]
    assert [h["residual"] for h in a] != [h["residual"] for h in c]


@pytest.mark.slow
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


@pytest.mark.slow  # over a second: the full suite runs it
def test_run_ends_with_the_mean_of_its_last_weights(tmp_path: Path) -> None:
    seen: list[dict[str, torch.Tensor]] = []

    def keep(model: Any) -> dict[str, float]:
        seen.append({k: v.clone() for k, v in model.state_dict().items()})
        return {}

    config = _tiny(
        "string-forced", iterations=12, lbfgs_fraction=0.0, average_window=4, monitor_every=1
    )
    result = train(config, monitor=keep, progress=False)
    for name, value in result.model.state_dict().items():
        expected = torch.stack([s[name] for s in seen[-4:]]).mean(0)
        torch.testing.assert_close(value, expected)
    final = result.model.state_dict()
    assert any(not torch.equal(value, seen[-1][name]) for name, value in final.items())
    # Stopped inside the window and resumed (Adam resumes bit for bit): the same mean.
    train(config, out_dir=tmp_path, progress=False, until=10)
    resumed = train(config, out_dir=tmp_path, resume=True, progress=False)
    for name, value in resumed.model.state_dict().items():
        torch.testing.assert_close(value, result.model.state_dict()[name])


def test_resume_refuses_another_configuration(tmp_path: Path) -> None:
    train(_tiny("string-forced", iterations=5), out_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        train(
            _tiny("string-forced", iterations=5, seed=3),
            out_dir=tmp_path,
            resume=True,
            progress=False,
        )


def test_not_a_checkpoint_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "checkpoint.pt"
    bad.write_text("not a checkpoint")
    with pytest.raises(UserError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    with pytest.raises(UserError, match="no checkpoint at"):
        load_checkpoint(tmp_path / "missing.pt")


@pytest.mark.parametrize("smoothing", ["0", "0.02"])
def test_initial_shape_matches_the_exact_solution_at_t0(smoothing: str) -> None:
    problem = make_problem("string-plucked", {"smoothing": smoothing})
    assert isinstance(problem, StringPlucked)
    x = np.linspace(0.0, 1.0, 201)
    expected = exact_solution(problem).grid(x, np.array([0.0]))[:, 0]
    got = initial_shape_jet(problem, torch.from_numpy(x)[:, None])[0][:, 0].numpy()
    np.testing.assert_allclose(got, expected, atol=1e-9 * problem.height)


def test_modal_term_sees_the_kink_that_points_cannot() -> None:
    # -c^2 times the sine coefficients of w'', by parts: 2 int w'' sin(n pi x) = -2 (n pi)^2 int w
    # sin(n pi x), computed from the triangle itself on a fine midpoint grid.
    problem = make_problem("string-plucked")
    assert isinstance(problem, StringPlucked)
    x = (np.arange(4000) + 0.5) / 4000
    n = np.arange(1, 6)
    by_parts = -2.0 * (np.pi * n) ** 2 * (np.sin(np.pi * np.outer(n, x)) @ problem.triangle(x))
    expected = -(problem.c**2) * by_parts / 4000
    got = kink_coefficients(problem, 5, torch.float64)
    assert got is not None and got.shape == (5,)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-5)
    smooth = make_problem("string-plucked-smooth")
    assert kink_coefficients(smooth, 5, torch.float64) is None


def test_pointwise_residual_sees_the_kink_through_its_first_modes() -> None:
    # On a midpoint grid, the series added to the pointwise residual has exactly the Dirac's
    # sine coefficients up to kink_modes and none above.
    from membrane_models.learned.training import Collocation

    model = build_model(recipe("string-plucked"))
    x = (torch.arange(512, dtype=torch.float64) + 0.5) / 512
    points = Collocation([x], torch.zeros(3, 1, dtype=torch.float64))
    series = kink_series(model, 8, points)
    assert series is not None and series.shape == (512, 1)
    coeffs, _ = sine_coefficients(series, [x], 12)
    expected = kink_coefficients(model.problem, 8, torch.float64)
    assert expected is not None
    np.testing.assert_allclose(coeffs[:8, 0].numpy(), expected.numpy(), rtol=1e-9)
    np.testing.assert_allclose(coeffs[8:, 0].numpy(), 0.0, atol=1e-9 * float(expected.abs().max()))
    smooth = build_model(recipe("string-plucked-smooth"))
    assert kink_series(smooth, 8, points) is None


@pytest.mark.parametrize(("every", "grids"), [(0, 1), (5, 3)])
@pytest.mark.slow  # over a second: the full suite runs it
def test_lbfgs_grid_is_redrawn_on_schedule_or_kept(
    monkeypatch: pytest.MonkeyPatch, every: int, grids: int
) -> None:
    import membrane_models.learned.training.loop as loop

    drawn: list[bool] = []
    original = loop.sample_collocation

    def counting(problem: Any, config: TrainConfig, generator: Any, fine: bool = False) -> Any:
        drawn.append(fine)
        return original(problem, config, generator, fine=fine)

    monkeypatch.setattr(loop, "sample_collocation", counting)
    config = _tiny("string-forced", lbfgs_resample_every=every)  # 15 L-BFGS iterations
    train(config, progress=False)
    assert sum(drawn) == grids


@pytest.mark.slow
@pytest.mark.parametrize("problem", ["string-forced", "string-plucked", "membrane-forced"])
def test_projected_residual_is_the_projection_of_the_pointwise_residual(problem: str) -> None:
    # By parts on a uniform grid against the pointwise residual projected on a fine one
    # (the kinked pluck's Dirac added analytically on both sides).
    from membrane_models.learned.training.collocation import forcing_grid
    from membrane_models.learned.training.losses import projected_residual

    model = build_model(recipe(problem))
    with torch.no_grad():
        coeffs, wavenumber, times = projected_residual(model, 6, 256)
        dims = model.spatial_dims
        n = 2048 if dims == 1 else 256
        axis = (torch.arange(n, dtype=torch.float64) + 0.5) / n
        space, time = model.space_grid_jet([axis] * dims), model.time_jet(times)
        c2 = model.problem.c**2
        residual = space.value @ time.d2[0].T - c2 * space.laplacian() @ time.value.T
        residual = residual - forcing_grid(model.problem, [axis] * dims, times[:, 0])
        expected, _ = sine_coefficients(residual, [axis] * dims, 6)
        kink = kink_coefficients(model.problem, 6, torch.float64)
        if kink is not None:
            expected = expected + kink[:, None]
    assert coeffs.shape == expected.shape == (6**dims, 256)
    assert wavenumber.shape == (6**dims,) and times.shape == (256, 1)
    scale = float(expected.abs().max())
    np.testing.assert_allclose(coeffs.numpy(), expected.numpy(), atol=1e-5 * scale)
