"""From a training checkpoint to ONNX graphs and their manifest, with a parity check.

``export_checkpoint`` writes, for ``MODEL.onnx``:

- ``MODEL.onnx``        full graph  ``xt`` (n, d+1) -> ``u`` (n, 1)
- ``MODEL.space.onnx``  space part  ``x`` (n, d) -> ``A`` (n, r)
- ``MODEL.time.onnx``   time part   ``t`` (m, 1) -> ``B`` (m, r)
- ``MODEL.json``        the manifest (``membrane_models.artifacts.manifest``), error measured by
  ``evaluate.evaluate_model`` on the written graphs.

All graphs are float32 with dynamic batch axes (opset 17). Before the manifest is written, each
graph is run with onnxruntime on the standard grid and compared with the torch model it came
from; a relative L2 difference above ``PARITY_TOLERANCE`` raises ``ParityError``.
"""

from __future__ import annotations

import copy
import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from membrane_errors import MembraneError
from membrane_models.artifacts.evaluate import evaluate_model, onnx_session, standard_axes
from membrane_models.artifacts.manifest import GraphFile, Manifest, sha256_of
from membrane_models.learned.training import load_checkpoint, model_from_checkpoint
from membrane_models.learned.transforms import PhysicalModel

__all__ = ["OPSET", "PARITY_TOLERANCE", "ParityError", "export_checkpoint", "export_model"]

logger = logging.getLogger(__name__)

OPSET = 17
PARITY_TOLERANCE = 1e-5


class ParityError(MembraneError):
    """onnxruntime's output differs from torch's by more than the tolerance."""


class _Full(nn.Module):
    def __init__(self, model: PhysicalModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, xt: Tensor) -> Tensor:
        out: Tensor = self.model(xt)
        return out


class _Space(_Full):
    def forward(self, x: Tensor) -> Tensor:
        return self.model.space(x)


class _Time(_Full):
    def forward(self, t: Tensor) -> Tensor:
        return self.model.time(t)


# role -> (wrapper, input name, output name, file suffix)
_ROLES: dict[str, tuple[type[_Full], str, str, str]] = {
    "full": (_Full, "xt", "u", ".onnx"),
    "space": (_Space, "x", "A", ".space.onnx"),
    "time": (_Time, "t", "B", ".time.onnx"),
}


def _graph_inputs(model: PhysicalModel) -> dict[str, np.ndarray]:
    """The parity check's inputs for each role: the standard grid (float64)."""
    axes = standard_axes(model.problem)
    mesh = np.meshgrid(*axes, indexing="ij")
    full = np.stack([m.reshape(-1) for m in mesh], axis=1)
    space_mesh = np.meshgrid(*axes[:-1], indexing="ij")
    space = np.stack([m.reshape(-1) for m in space_mesh], axis=1)
    return {"full": full, "space": space, "time": axes[-1][:, None]}


def _write_graph(module: nn.Module, example: Tensor, path: Path, inp: str, out: str) -> None:
    # The TorchScript exporter (dynamo=False) needs no onnxscript and handles these small
    # graphs exactly; its deprecation notice is not actionable here.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        _onnx_export(module, example, path, inp, out)


def _onnx_export(module: nn.Module, example: Tensor, path: Path, inp: str, out: str) -> None:
    torch.onnx.export(
        module,
        (example,),
        str(path),
        input_names=[inp],
        output_names=[out],
        dynamic_axes={inp: {0: "n"}, out: {0: "n"}},
        opset_version=OPSET,
        dynamo=False,
    )


def _relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    norm = float(np.linalg.norm(b))
    return float(np.linalg.norm(a - b)) / (norm if norm > 0.0 else 1.0)


def export_model(model: PhysicalModel, out: Path) -> dict[str, GraphFile]:
    """Write the three graphs of ``model`` beside ``out`` and check their parity with torch.

    Returns the manifest's ``graphs`` entry. Raises ``ParityError`` if any graph disagrees with
    the (float64) torch model by more than ``PARITY_TOLERANCE`` in relative L2.
    """
    reference = copy.deepcopy(model).double().eval()
    exported = copy.deepcopy(model).float().eval()
    inputs = _graph_inputs(model)
    stem = out.name.removesuffix(".onnx")
    graphs: dict[str, GraphFile] = {}
    for role, (wrapper, inp, outp, suffix) in _ROLES.items():
        path = out.with_name(stem + suffix)
        example = torch.from_numpy(inputs[role][:4]).float()
        _write_graph(wrapper(exported), example, path, inp, outp)
        got = onnx_session(path).run(None, {inp: inputs[role].astype(np.float32)})[0]
        with torch.no_grad():
            want = wrapper(reference)(torch.from_numpy(inputs[role])).numpy()
        if got.shape != want.shape:
            raise ParityError(f"{path.name}: onnxruntime shape {got.shape} != torch {want.shape}")
        diff = _relative_difference(got.astype(np.float64), want)
        logger.info("parity %s: relative L2 difference %.2e", role, diff)
        if not diff <= PARITY_TOLERANCE:
            raise ParityError(
                f"{path.name}: onnxruntime differs from torch by {diff:.2e} (relative L2) "
                f"> {PARITY_TOLERANCE:.0e}"
            )
        graphs[role] = GraphFile(file=path.name, sha256=sha256_of(path), input=inp, output=outp)
    return graphs


def _architecture(model: PhysicalModel) -> dict[str, Any]:
    return {**model.core.config(), "transform": model.transform_config()}


def _domain(model: PhysicalModel) -> dict[str, list[float]]:
    domain = {axis: [0.0, 1.0] for axis in model.problem.axes[:-1]}
    domain["t"] = [0.0, model.t_end]
    return domain


def export_checkpoint(checkpoint: Path, out: Path) -> Manifest:
    """Export a checkpoint to ``out`` (MODEL.onnx) plus part-graphs and the manifest.

    The model's name is the file's stem (``MODEL``), and the manifest is ``MODEL.json``. The
    manifest's error is measured on the written full graph with onnxruntime.
    """
    data = load_checkpoint(checkpoint)
    model, config = model_from_checkpoint(data)
    out.parent.mkdir(parents=True, exist_ok=True)
    graphs = export_model(model, out)
    history = data.get("history") or []
    final = {k: v for k, v in (history[-1] if history else {}).items() if k != "wall_time"}
    manifest = Manifest(
        name=out.name.removesuffix(".onnx"),
        problem=config.problem,
        parameters=model.problem.parameters(),
        domain=_domain(model),
        architecture=_architecture(model),
        graphs=graphs,
        rank=model.rank,
        bias=0.0,
        training={
            "iterations": int(data["iteration"]),
            "adam_iterations": config.adam_iterations,
            "lbfgs_iterations": config.lbfgs_iterations,
            "wall_time_s": round(float(data["wall_time"]), 1),
            "seed": config.seed,
            "command": data.get("command", ""),
            "final_loss": final,
            "dtype": config.dtype,
            "machine": "2-core CPU, torch CPU build",
        },
    )
    path = out.with_name(f"{manifest.name}.json")
    manifest.write(path)
    report = evaluate_model(Manifest.read(path))
    manifest = Manifest.read(path)
    final_manifest = Manifest(**{**_fields(manifest), "error": report.to_dict()})
    final_manifest.write(path)
    return Manifest.read(path)


def _fields(manifest: Manifest) -> dict[str, Any]:
    return {f: getattr(manifest, f) for f in manifest.__dataclass_fields__ if f != "error"}
