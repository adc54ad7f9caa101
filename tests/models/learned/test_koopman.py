"""The Koopman latent model: eigenvalues in the unit disc, a short run whose loss falls and
resumes bit for bit, exported graphs in parity with torch, and the shipped model's manifest."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from membrane_errors import UserError
from membrane_models.artifacts.evaluate import onnx_session
from membrane_models.artifacts.koopman_evaluate import BANDS, TestSplit, onnx_rollout
from membrane_models.artifacts.koopman_manifest import find_koopman_model
from membrane_models.data.koopman import DatasetSpec, write_datasets
from membrane_models.learned.koopman_export import PARITY_TOLERANCE, write_graphs
from membrane_models.learned.koopman_network import KoopmanConfig, KoopmanNetwork
from membrane_models.learned.koopman_training import (
    KoopmanTrainConfig,
    load_koopman_checkpoint,
    loss_terms,
    train_koopman,
)

SMALL = KoopmanConfig(pairs=8, width=32, aux_width=16)  # sin m pi x, m <= 8: all kept


def _perturbed(config: KoopmanConfig = SMALL) -> KoopmanNetwork:
    """A network whose residual branches and auxiliary network are not zero (as trained)."""
    torch.manual_seed(3)
    model = KoopmanNetwork(config)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    return model.double().eval()


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Sine trajectories only (one or two modes each: the solver is fast), 30 steps."""
    out = tmp_path_factory.mktemp("koopman-data")
    write_datasets(DatasetSpec(counts=(6, 1, 2), families=("sine",), steps=30), out)
    return out


@pytest.mark.parametrize("variant", ["aux", "fixed"])
def test_every_eigenvalue_lies_in_the_closed_unit_disc(variant: str) -> None:
    model = _perturbed(dataclasses.replace(SMALL, variant=variant))
    z = 50.0 * torch.randn(8, SMALL.latent, dtype=torch.float64)  # far beyond the data
    for state in z:
        moduli = np.abs(np.linalg.eigvals(model.step_matrix(state).detach().numpy()))
        assert moduli.max() <= 1.0 + 1e-12
    with torch.no_grad():  # a step never grows the latent state, however many are taken
        stepped = model.advance(z, 10_000.0)
    assert torch.all(torch.linalg.norm(stepped, dim=1) <= torch.linalg.norm(z, dim=1) * (1 + 1e-12))


def test_untrained_it_is_the_linear_modal_model() -> None:
    model = KoopmanNetwork(SMALL).double()
    x = torch.arange(1, 129, dtype=torch.float64) / 129
    q = torch.tensor([0.01, -0.004, 0.002, 0.001, 0, 0, 0, 0], dtype=torch.float64)
    shape = torch.sin(torch.pi * torch.outer(x, torch.arange(1.0, 9.0, dtype=torch.float64))) @ q
    state = torch.cat([shape, torch.zeros(128, dtype=torch.float64)])[None]
    with torch.no_grad():
        after = model.decode(model.advance(model.encode(state), 37.0))[0, :128]
    omega = torch.pi * torch.arange(1.0, 9.0, dtype=torch.float64)
    want = torch.sin(torch.pi * torch.outer(x, torch.arange(1.0, 9.0))) @ (
        q * torch.cos(omega * 0.37)
    )
    assert torch.allclose(after, want.to(after.dtype), atol=1e-8)


@pytest.mark.slow
def test_a_short_run_lowers_the_loss_and_resumes_bit_for_bit(
    tiny_data: Path, tmp_path: Path
) -> None:
    torch.set_num_threads(1)
    config = KoopmanTrainConfig(network=SMALL, iterations=80, batch=32, checkpoint_every=40)
    data = np.load(tiny_data / "train.npz")
    states = torch.from_numpy(np.concatenate([data["u"], data["u_t"]], 2).astype(np.float32))

    def loss(model: KoopmanNetwork) -> float:
        generator = torch.Generator().manual_seed(7)
        with torch.no_grad():
            terms = loss_terms(model, states, generator, 256)
        return sum(w * float(terms[n]) for w, n in zip(config.weights, terms, strict=True))

    torch.manual_seed(config.seed)
    before = loss(KoopmanNetwork(SMALL))
    whole = train_koopman(config, tiny_data, tmp_path / "whole", progress=False)
    assert loss(whole.model) < 0.7 * before
    train_koopman(config, tiny_data, tmp_path / "split", progress=False, until=40)
    resumed = train_koopman(config, tiny_data, tmp_path / "split", resume=True, progress=False)
    for a, b in zip(whole.model.parameters(), resumed.model.parameters(), strict=True):
        assert torch.equal(a, b)
    saved = load_koopman_checkpoint(tmp_path / "split" / "checkpoint.pt")
    assert saved["iteration"] == 80 and len(saved["history"]) == 80


@pytest.mark.slow
def test_exported_graphs_match_torch(tiny_data: Path, tmp_path: Path) -> None:
    model = _perturbed()
    states = TestSplit.read(tiny_data / "test.npz").states[:, 0]
    graphs, parity = write_graphs(model, tmp_path / "k.onnx", states)
    assert set(graphs) == {"encoder", "step", "decoder"}
    assert max(parity.values()) <= PARITY_TOLERANCE
    encoder = onnx_session(tmp_path / graphs["encoder"].file)
    stepper = onnx_session(tmp_path / graphs["step"].file)
    z = encoder.run(None, {"state": states.astype(np.float32)})[0]
    with torch.no_grad():
        want = model.advance(model.encode(torch.from_numpy(states))).numpy()
    got = stepper.run(None, {"z": z})[0]
    assert np.linalg.norm(got - want) <= 1e-5 * np.linalg.norm(want)


def test_the_shipped_model_keeps_its_promises() -> None:
    manifest = find_koopman_model("koopman-string")
    assert manifest is not None and manifest.latent == 21 and manifest.points == 128
    assert manifest.spectrum["modulus_max"] <= 1.0 + 1e-6
    assert max(manifest.parity.values()) <= PARITY_TOLERANCE
    assert manifest.training["wall_time_s"] < 20 * 60
    assert "membrane train koopman-string" in manifest.training["command"]
    rows = manifest.errors["rows"]
    assert {r["band"] for r in rows} >= set(BANDS)
    assert {str(s) for s in manifest.errors["steps"]} == {"1", "10", "100", "1000"}
    stepper = onnx_session(manifest.verify("step"))  # sha256 checked
    z = (np.random.default_rng(0).standard_normal((16, manifest.latent)) * 30).astype(np.float32)
    stepped = z
    for _ in range(100):
        stepped = stepper.run(None, {"z": stepped})[0]
    ratio = np.linalg.norm(stepped, axis=1) / np.linalg.norm(z, axis=1)
    assert np.all(ratio <= 1.0 + 1e-4)


def test_re_encoding_decodes_and_encodes_again_every_n_steps(tiny_data: Path) -> None:
    manifest = find_koopman_model("koopman-string")
    assert manifest is not None
    initial = TestSplit.read(tiny_data / "test.npz").states[:, 0]
    encoder, stepper, decoder = (onnx_session(manifest.verify(role))
                                 for role in ("encoder", "step", "decoder"))  # fmt: skip
    z = encoder.run(None, {"state": initial.astype(np.float32)})[0]
    for k in range(1, 5):
        z = stepper.run(None, {"z": z})[0]
        if k % 2 == 0:  # every 2 steps: decode, encode again
            z = encoder.run(None, {"state": decoder.run(None, {"z": z})[0]})[0]
    expected = decoder.run(None, {"z": z})[0][:, : manifest.points]
    assert np.array_equal(onnx_rollout(manifest, 2)(initial, [4])[4], expected)
    plain = onnx_rollout(manifest)(initial, [4])[4]
    assert not np.array_equal(plain, expected)  # re-encoding changes the latent
    with pytest.raises(UserError, match="at least 1 step"):
        onnx_rollout(manifest, 0)
