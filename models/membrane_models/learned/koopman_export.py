"""From a Koopman checkpoint to its encoder, step and decoder graphs, checked, with a manifest.

For ``MODEL.onnx`` it writes ``MODEL.encoder.onnx``, ``MODEL.step.onnx``, ``MODEL.decoder.onnx``
and ``MODEL.json`` (``artifacts.koopman_manifest``). Each graph is run with onnxruntime on the
test split's states (the encoder), their latents (step, decoder) and compared with the float64
torch network; above ``PARITY_TOLERANCE`` relative L2 the export fails with ``ParityError``. The
manifest's error table is measured on the written graphs (``koopman_evaluate``), as are the
eigenvalue moduli of K(z) at the test states and 10^5 steps of decoded energy.
"""

from __future__ import annotations

import copy
import platform
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from membrane_models.artifacts.evaluate import onnx_session
from membrane_models.artifacts.koopman_evaluate import (
    TestSplit,
    error_table,
    long_horizon,
    onnx_rollout,
)
from membrane_models.artifacts.koopman_manifest import KoopmanManifest
from membrane_models.artifacts.manifest import GraphFile, sha256_of
from membrane_models.learned.export import OPSET, ParityError
from membrane_models.learned.koopman_network import KoopmanNetwork
from membrane_models.learned.koopman_training import (
    load_koopman_checkpoint,
    model_from_koopman_checkpoint,
)

__all__ = ["PARITY_TOLERANCE", "eigenvalue_moduli", "export_koopman", "write_graphs"]

PARITY_TOLERANCE = 1e-5
LONG_HORIZON = 100_000


class _Encoder(nn.Module):
    def __init__(self, model: KoopmanNetwork) -> None:
        super().__init__()
        self.model = model

    def forward(self, state: Tensor) -> Tensor:
        return self.model.encode(state)


class _Step(_Encoder):
    def forward(self, z: Tensor) -> Tensor:
        return self.model.advance(z)


class _Decoder(_Encoder):
    def forward(self, z: Tensor) -> Tensor:
        return self.model.decode(z)


# role -> (wrapper, input, output)
_ROLES: dict[str, tuple[type[_Encoder], str, str]] = {
    "encoder": (_Encoder, "state", "z"),
    "step": (_Step, "z", "z_next"),
    "decoder": (_Decoder, "z", "state"),
}


def _export(module: nn.Module, example: Tensor, path: Path, inp: str, out: str) -> None:
    with warnings.catch_warnings():  # the TorchScript exporter's deprecation: not actionable
        warnings.simplefilter("ignore", DeprecationWarning)
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


def write_graphs(
    model: KoopmanNetwork, out: Path, states: np.ndarray
) -> tuple[dict[str, GraphFile], dict[str, float]]:
    """Write the three graphs beside ``out`` and check each against torch on ``states``."""
    reference = copy.deepcopy(model).double().eval()
    exported = copy.deepcopy(model).float().eval()
    with torch.no_grad():
        latents = reference.encode(torch.from_numpy(states)).numpy()
    inputs = {"encoder": states, "step": latents, "decoder": latents}
    stem = out.name.removesuffix(".onnx")
    graphs: dict[str, GraphFile] = {}
    parity: dict[str, float] = {}
    for role, (wrapper, inp, outp) in _ROLES.items():
        path = out.with_name(f"{stem}.{role}.onnx")
        example = torch.from_numpy(inputs[role][:2]).float()
        _export(wrapper(exported), example, path, inp, outp)
        got = onnx_session(path).run(None, {inp: inputs[role].astype(np.float32)})[0]
        with torch.no_grad():
            want = wrapper(reference)(torch.from_numpy(inputs[role])).numpy()
        diff = float(np.linalg.norm(got - want) / max(float(np.linalg.norm(want)), 1e-300))
        if got.shape != want.shape or not diff <= PARITY_TOLERANCE:
            raise ParityError(f"{path.name}: onnxruntime differs from torch by {diff:.2e}")
        parity[role] = diff
        graphs[role] = GraphFile(file=path.name, sha256=sha256_of(path), input=inp, output=outp)
    return graphs, parity


def eigenvalue_moduli(model: KoopmanNetwork, states: np.ndarray) -> dict[str, Any]:
    """Moduli of K(z)'s eigenvalues at each state's latent, and the frequencies they turn at."""
    reference = copy.deepcopy(model).double().eval()
    moduli: list[np.ndarray] = []
    with torch.no_grad():
        latents = reference.encode(torch.from_numpy(states))
        for z in latents:
            moduli.append(np.abs(np.linalg.eigvals(reference.step_matrix(z).numpy())))
        angles = reference.angles(latents).numpy()
    frequencies = angles / model.config.dt
    linear = np.pi * model.config.c * np.arange(1, model.config.pairs + 1)
    ratio = frequencies / linear
    return {
        "modulus_min": float(np.min(moduli)),
        "modulus_max": float(np.max(moduli)),
        "states": len(moduli),
        "parametrisation": "rotations exp(+-i theta_j(z)), modulus 1 by construction; the "
        "invariant's eigenvalue 1",
        "frequency_over_linear_min": float(ratio.min()),
        "frequency_over_linear_max": float(ratio.max()),
        "base_frequencies": [float(v) for v in torch.exp(model.log_frequency).detach()],
    }


def export_koopman(checkpoint: Path, out: Path, data_dir: Path | None = None) -> KoopmanManifest:
    """Export ``checkpoint`` as ``out`` (MODEL.onnx names the stem) with its manifest."""
    data = load_koopman_checkpoint(checkpoint)
    model = model_from_koopman_checkpoint(data)
    folder = Path(data_dir) if data_dir is not None else Path(data["data"])
    test = TestSplit.read(folder / "test.npz")
    out.parent.mkdir(parents=True, exist_ok=True)
    graphs, parity = write_graphs(model, out, test.states[:, 0])
    history = data.get("history") or []
    final = {k: v for k, v in (history[-1] if history else {}).items() if k != "wall_time"}
    config = data["config"]
    parameters = data["data_parameters"]
    manifest = KoopmanManifest(
        name=out.name.removesuffix(".onnx"),
        problem="string-kirchhoff",
        parameters={"c": float(parameters["c"]), "stretch": float(parameters["k"])},
        points=model.config.points,
        dt=model.config.dt,
        latent=model.config.latent,
        architecture={
            "name": f"koopman-{model.config.variant}",
            **model.config.to_dict(),
            "encoder": "outer residual ReLU MLP (4 hidden layers), inner linear to the latent",
            "decoder": "inner linear from the latent, outer residual ReLU MLP (mirrored)",
        },
        graphs=graphs,
        spectrum=eigenvalue_moduli(model, test.states[:, 0]),
        training={
            "iterations": int(data["iteration"]),
            "wall_time_s": round(float(data["wall_time"]), 1),
            "seed": int(config["seed"]),
            "batch": int(config["batch"]),
            "command": data.get("command", ""),
            "final_loss": final,
            "data": {
                k: parameters[k]
                for k in ("seed", "counts", "steps", "dt", "k", "c", "nonlinearity")
            },
            "split_used": "train (validation for the progress figure only)",
            "machine": f"2-core CPU, torch {torch.__version__}, one thread, {platform.machine()}",
        },
        parity=parity,
    )
    path = out.with_name(f"{manifest.name}.json")
    manifest.write(path)
    manifest = KoopmanManifest.read(path)
    table = error_table(onnx_rollout(manifest), test)
    table["long_horizon"] = long_horizon(manifest, test, LONG_HORIZON)
    manifest = manifest.with_errors(table)
    manifest.write(path)
    return KoopmanManifest.read(path)
