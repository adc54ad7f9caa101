"""ONNX export: torch vs onnxruntime parity, the manifest round trip, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from membrane_cli.dispatcher import main
from membrane_models.artifacts.evaluate import evaluate_model, onnx_session
from membrane_models.artifacts.manifest import Manifest
from membrane_models.artifacts.zoo_index import resolve_model
from membrane_models.learned.architectures import (
    ArchConfig,
    GaussianFeatures,
    HarmonicFeatures,
    SpinnConfig,
    StmsffnConfig,
)
from membrane_models.learned.export import PARITY_TOLERANCE, export_checkpoint, export_model
from membrane_models.learned.training import build_model, recipe, train

TINY = SpinnConfig(
    rank=4,
    width=8,
    depth=2,
    space_features=HarmonicFeatures(3),
    time_features=GaussianFeatures(3, sigma=3.0),
)
TINY_STMSFFN = StmsffnConfig(width=8, hidden=2, sigmas_x=(1.0,), sigmas_t=(1.0, 10.0), shared=False)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("problem", "arch"),
    [
        ("string-forced", TINY),
        ("membrane-forced", TINY),
        ("string-plucked", TINY),
        ("membrane-forced", TINY_STMSFFN),
    ],
)
def test_untrained_network_parity(tmp_path: Path, problem: str, arch: ArchConfig) -> None:
    model = build_model(recipe(problem, arch=arch))
    graphs = export_model(model, tmp_path / "m.onnx")  # raises ParityError above 1e-5
    assert set(graphs) == {"full", "space", "time"}
    # Independently of the exporter's own check: each graph against torch in float64.
    d = model.spatial_dims
    rng = np.random.default_rng(0)
    x = rng.random((50, d))
    t = rng.random((30, 1)) * model.t_end
    space = onnx_session(tmp_path / "m.space.onnx").run(None, {"x": x.astype(np.float32)})[0]
    time = onnx_session(tmp_path / "m.time.onnx").run(None, {"t": t.astype(np.float32)})[0]
    xt = np.concatenate([np.repeat(x, 30, 0), np.tile(t, (50, 1))], 1)
    full = onnx_session(tmp_path / "m.onnx").run(None, {"xt": xt.astype(np.float32)})[0]
    with torch.no_grad():
        reference = model.double()
        want_space = reference.space(torch.from_numpy(x)).numpy()
        want_time = reference.time(torch.from_numpy(t)).numpy()
        want_full = reference(torch.from_numpy(xt)).numpy()
    assert space.shape == (50, model.rank) and time.shape == (30, model.rank)
    assert _relative(space, want_space) <= PARITY_TOLERANCE
    assert _relative(time, want_time) <= PARITY_TOLERANCE
    assert _relative(full, want_full) <= PARITY_TOLERANCE
    # The contract the server relies on: u = A @ B^T (+ bias 0).
    assert _relative((space @ time.T).reshape(-1, 1), full) <= PARITY_TOLERANCE


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Manifest:
    root = tmp_path_factory.mktemp("export")
    config = recipe(
        "string-forced",
        arch=TINY,
        iterations=30,
        lbfgs_fraction=0.2,
        space_points=16,
        time_points=16,
        lbfgs_space_points=16,
        lbfgs_time_points=16,
    )
    train(config, out_dir=root / "run", command="membrane train string-forced ...", progress=False)
    return export_checkpoint(root / "run" / "checkpoint.pt", root / "model" / "tiny.onnx")


@pytest.mark.slow
def test_manifest_round_trip(exported: Manifest) -> None:
    assert exported.path is not None
    again = Manifest.read(exported.path)
    assert again == exported
    assert resolve_model(exported.path.with_suffix(".onnx")) == exported
    for role in ("full", "space", "time"):
        exported.verify(role)  # sha256 of every graph matches
    assert exported.separable and exported.rank == 4 and exported.bias == 0.0
    assert exported.domain == {"x": [0.0, 1.0], "t": [0.0, 1.0]}
    assert exported.parameters["c"] == 10.0
    assert exported.training["iterations"] == 30
    assert exported.training["command"] == "membrane train string-forced ..."
    assert exported.architecture["name"] == "spinn"


@pytest.mark.slow
def test_manifest_error_is_what_evaluate_measures(exported: Manifest) -> None:
    report = evaluate_model(exported)
    assert report.relative_l2 == exported.error["relative_l2"]
    assert report.max_abs == exported.error["max_abs"]
    assert exported.error["grid"] == [101, 101]


@pytest.mark.slow
def test_altered_graph_is_refused(exported: Manifest, tmp_path: Path) -> None:
    assert exported.path is not None
    copy = tmp_path / "copy"
    copy.mkdir()
    for f in exported.path.parent.iterdir():
        (copy / f.name).write_bytes(f.read_bytes())
    graph = copy / "tiny.time.onnx"
    graph.write_bytes(graph.read_bytes() + b"\0")
    with pytest.raises(ValueError, match="sha256"):
        Manifest.read(copy / "tiny.json").verify("time")


@pytest.mark.slow
def test_cli_evaluate_prints_the_manifest_figure(
    exported: Manifest, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert exported.path is not None
    plot = tmp_path / "plot.png"
    assert (
        main(["evaluate", str(exported.path.with_suffix(".onnx")), "--json", "--plot", str(plot)])
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert f"{out['relative_l2']:.3e}" == f"{exported.error['relative_l2']:.3e}"
    assert plot.stat().st_size > 1000


def test_cli_bad_input_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["export", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "m.onnx")]) == 2
    assert main(["export", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "m.txt")]) == 2
    assert main(["evaluate", "no-such-model"]) == 2
    assert main(["train", "no-such-problem", "--out", str(tmp_path / "r")]) == 2
    assert main(["train", "string-forced", "--set", "c=-1", "--out", str(tmp_path / "r")]) == 2
    assert main(["train", "string-forced", "--iterations", "0", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 6 and all(line.startswith("membrane ") for line in err)
    assert not (tmp_path / "r").exists()
