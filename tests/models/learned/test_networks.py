"""The networks' forward-propagated derivatives against autograd, and their separable form."""

from __future__ import annotations

import json

import pytest
import torch

from membrane_models.artifacts.zoo_index import ZOO_DIR
from membrane_models.learned.architectures import (
    GaussianFeatures,
    HarmonicFeatures,
    SpinnConfig,
    StmsffnConfig,
    arch_from_dict,
)
from membrane_models.learned.networks import (
    AxisNetwork,
    SeparableCore,
    SeparablePINN,
    STMsFFN,
    core_from_config,
)
from membrane_models.learned.transforms import PhysicalModel, characteristic_amplitude
from membrane_models.problems import StringPlucked, make_problem

D = torch.float64


def _small_core(name: str, dims: int) -> SeparableCore:
    if name.startswith("spinn"):
        arch = SpinnConfig(
            rank=5,
            width=8,
            depth=2,
            space_features=HarmonicFeatures(3),
            time_features=GaussianFeatures(3, sigma=2.0),
            skip=name == "spinn-skip",
        )
        core = SeparablePINN(dims, arch)
        for module in core.modules():  # the skip paths start at zero: give them weights
            if isinstance(module, AxisNetwork) and module.skip is not None:
                torch.nn.init.normal_(module.skip.weight)
        return core
    published = StmsffnConfig(width=8, hidden=2, sigmas_x=(1.0,), sigmas_t=(1.0, 5.0), shared=False)
    return STMsFFN(dims, published)


def _autograd_laplacian(values: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    lap = torch.zeros_like(values)
    for k in range(values.shape[1]):
        grad = torch.autograd.grad(values[:, k].sum(), points, create_graph=True)[0]
        for a in range(points.shape[1]):
            lap[:, k] += torch.autograd.grad(grad[:, a].sum(), points, retain_graph=True)[0][:, a]
    return lap


CASES = [
    ("spinn", "string-forced"),
    ("spinn", "membrane-forced"),
    ("spinn", "string-plucked-smooth"),
    ("spinn-skip", "string-plucked"),
    ("spinn-skip", "membrane-forced"),
    ("stmsffn", "string-forced"),
    ("stmsffn", "membrane-forced"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("arch", "problem_name"), CASES)
def test_space_jet_matches_autograd(arch: str, problem_name: str) -> None:
    problem = make_problem(problem_name)
    model = PhysicalModel(_small_core(arch, problem.spatial_dims), problem, 1e-3).double()
    axes = [torch.rand(4, dtype=D) for _ in range(problem.spatial_dims)]
    jet = model.space_grid_jet(axes)
    mesh = torch.meshgrid(*axes, indexing="ij")
    points = torch.stack([m.reshape(-1) for m in mesh], 1).requires_grad_(True)
    values = model.space(points)
    torch.testing.assert_close(jet.value, values.detach(), rtol=1e-12, atol=1e-15)
    expected = _autograd_laplacian(values, points).detach()
    torch.testing.assert_close(jet.laplacian(), expected, rtol=1e-9, atol=1e-12)


def _second(first: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    if not first.requires_grad:  # a constant column (the pluck's B = 1)
        return torch.zeros(t.shape[0], dtype=D)
    return torch.autograd.grad(first.sum(), t, retain_graph=True)[0][:, 0]


@pytest.mark.parametrize(("arch", "problem_name"), CASES)
def test_time_jet_matches_autograd(arch: str, problem_name: str) -> None:
    problem = make_problem(problem_name)
    model = PhysicalModel(_small_core(arch, problem.spatial_dims), problem, 1e-3).double()
    t = (torch.rand(6, 1, dtype=D) * problem.t_end).requires_grad_(True)
    values = model.time(t)
    jet = model.time_jet(t)
    first = torch.stack(
        [
            torch.autograd.grad(values[:, k].sum(), t, create_graph=True)[0][:, 0]
            for k in range(values.shape[1])
        ],
        1,
    )
    second = torch.stack([_second(first[:, k], t) for k in range(values.shape[1])], 1)
    torch.testing.assert_close(jet.value, values.detach())
    torch.testing.assert_close(jet.d1[0], first.detach(), rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(jet.d2[0], second.detach(), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(("arch", "problem_name"), CASES)
def test_full_output_is_space_times_time(arch: str, problem_name: str) -> None:
    problem = make_problem(problem_name)
    model = PhysicalModel(_small_core(arch, problem.spatial_dims), problem, 1e-3).double()
    x = torch.rand(7, problem.spatial_dims, dtype=D)
    t = torch.rand(5, 1, dtype=D) * problem.t_end
    grid = model.space(x) @ model.time(t).T
    xt = torch.cat([x.repeat_interleave(5, 0), t.repeat(7, 1)], 1)
    torch.testing.assert_close(model(xt).reshape(7, 5), grid)


@pytest.mark.parametrize(("arch", "problem_name"), CASES)
def test_space_on_a_grid_is_space_at_its_points(arch: str, problem_name: str) -> None:
    problem = make_problem(problem_name)
    model = PhysicalModel(_small_core(arch, problem.spatial_dims), problem, 1e-3).double()
    axes = [torch.rand(n, dtype=D) for n in (6, 4)[: problem.spatial_dims]]
    mesh = torch.meshgrid(*axes, indexing="ij")
    points = torch.stack([m.reshape(-1) for m in mesh], 1)
    torch.testing.assert_close(model.space_grid(axes), model.space(points))


def test_hard_conditions_hold_for_an_untrained_network() -> None:
    problem = make_problem("membrane-forced")
    model = PhysicalModel(_small_core("spinn", 2), problem, 1e-3).double()
    edge = torch.tensor([[0.0, 0.3], [1.0, 0.7], [0.4, 0.0], [0.6, 1.0]], dtype=D)
    assert torch.all(model.space(edge) == 0.0)
    jet = model.time_jet(torch.zeros(1, 1, dtype=D))
    assert torch.all(jet.value == 0.0) and torch.all(jet.d1 == 0.0)


def test_plucked_model_starts_from_the_pluck() -> None:
    problem = make_problem("string-plucked")
    assert isinstance(problem, StringPlucked)
    model = PhysicalModel(_small_core("spinn", 1), problem, problem.height).double()
    x = torch.linspace(0, 1, 11, dtype=D)[:, None]
    u0 = model(torch.cat([x, torch.zeros_like(x)], 1))[:, 0]
    torch.testing.assert_close(u0, torch.from_numpy(problem.triangle(x[:, 0].numpy())))


def test_config_round_trip_and_unknown_name() -> None:
    for name in ("stmsffn", "spinn", "spinn-skip"):
        core = _small_core(name, 1)
        assert core_from_config(core.config()).config() == core.config()
        assert isinstance(core, SeparablePINN | STMsFFN)
        assert arch_from_dict(core.config()) == core.arch
    assert "skip" not in _small_core("spinn", 1).config()  # earlier checkpoints still match
    with pytest.raises(ValueError, match="unknown architecture"):
        core_from_config({"name": "koopman", "spatial_dims": 1, "seed": 0})
    with pytest.raises(ValueError, match="no field 'depht'"):
        arch_from_dict({"name": "spinn", "rank": 4, "depht": 2})
    with pytest.raises(ValueError, match="must be even"):
        StmsffnConfig(width=7)


def test_shipped_manifests_rebuild_with_their_architecture() -> None:
    # The manifests' plain form is what the typed configs write, key for key and in order.
    from membrane_models.learned.training import build_model, recipe

    for name in ("string-forced", "membrane-forced", "string-plucked", "string-plucked-smooth"):
        manifest = json.loads((ZOO_DIR / f"{name}.json").read_text())
        shipped = {k: v for k, v in manifest["architecture"].items() if k != "transform"}
        model = build_model(recipe(name))
        assert list(model.core.config().items()) == list(shipped.items())


def test_characteristic_amplitude_is_the_size_of_the_response() -> None:
    # The static deflection under the peak force; the true peaks are 5.6e-4 and 4.8e-4.
    assert 3e-4 < characteristic_amplitude(make_problem("string-forced")) < 1e-3
    assert 2.5e-4 < characteristic_amplitude(make_problem("membrane-forced")) < 1e-3
    assert characteristic_amplitude(make_problem("string-plucked")) == 0.05
