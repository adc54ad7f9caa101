"""The shipped models: their error re-measured with onnxruntime equals the manifest's figure."""

from __future__ import annotations

import numpy as np
import pytest

from membrane_models.artifacts.evaluate import evaluate_model, onnx_session
from membrane_models.artifacts.zoo_index import list_models, resolve_model

# The accuracy each shipped model must reach (relative L2 on the standard grid).
TARGETS = {
    "string-forced": 1e-3,
    "string-plucked": 1e-2,
    "string-plucked-smooth": 1e-3,
    "membrane-forced": 3e-3,
}

SHIPPED = list_models()


def test_the_zoo_ships_a_model_per_problem() -> None:
    assert {"string-forced", "string-plucked", "membrane-forced"} <= set(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_error_matches_manifest(name: str) -> None:
    manifest = resolve_model(name)
    report = evaluate_model(manifest)  # verifies the sha256 before loading
    assert f"{report.relative_l2:.3g}" == f"{manifest.error['relative_l2']:.3g}"
    assert f"{report.max_abs:.3g}" == f"{manifest.error['max_abs']:.3g}"


@pytest.mark.parametrize("name", [name for name in SHIPPED if name in TARGETS])
def test_meets_its_target(name: str) -> None:
    manifest = resolve_model(name)
    assert manifest.error["relative_l2"] <= TARGETS[name]


@pytest.mark.parametrize("name", SHIPPED)
def test_separable_parts_rebuild_the_full_graph(name: str) -> None:
    manifest = resolve_model(name)
    assert manifest.separable, "every shipped model ships space and time graphs"
    d = manifest.spatial_dims
    rng = np.random.default_rng(1)
    x = rng.random((40, d)).astype(np.float32)
    t = (rng.random((9, 1)) * manifest.domain["t"][1]).astype(np.float32)
    a = onnx_session(manifest.verify("space")).run(None, {"x": x})[0]
    b = onnx_session(manifest.verify("time")).run(None, {"t": t})[0]
    xt = np.concatenate([np.repeat(x, 9, 0), np.tile(t, (40, 1))], 1)
    u = onnx_session(manifest.verify("full")).run(None, {"xt": xt})[0]
    assert a.shape == (40, manifest.rank) and b.shape == (9, manifest.rank)
    parts = (a.astype(np.float64) @ b.T.astype(np.float64)).reshape(-1, 1) + manifest.bias
    assert np.linalg.norm(parts - u) <= 1e-5 * np.linalg.norm(u)


@pytest.mark.parametrize("name", SHIPPED)
def test_manifest_records_how_it_was_made(name: str) -> None:
    manifest = resolve_model(name)
    training = manifest.training
    assert training["command"].startswith(f"membrane train {manifest.problem} ")
    assert 0 < training["wall_time_s"] < 20 * 60
    assert training["iterations"] > 0
