"""The Kirchhoff string's datasets: shapes, scaling, splits, determinism, the command."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

from membrane_cli.dispatcher import main
from membrane_models.commands.data import _Progress
from membrane_models.data.koopman import (
    SPLITS,
    DatasetError,
    DatasetSpec,
    initial_state,
    write_datasets,
)
from membrane_models.exact.kirchhoff_carrier import sine_basis
from membrane_models.exact.plucked import pluck_extension
from membrane_models.problems import StringPlucked, make_problem
from membrane_models.problems.string_shapes import FAMILIES, pluck, square_pulse

SMALL = DatasetSpec(counts=(2, 1, 1), steps=20, families=("square", "noise", "pluck"))


def _read(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:  # allow_pickle is off: every array is plain
        return {key: data[key] for key in data.files}


def test_square_pulse_is_smoothed_over_the_stated_width() -> None:
    # Away from the ends, the pulse convolved with a Gaussian of s.d. w is a difference of
    # normal CDFs; its sine series must be that function.
    start, end, width = 0.3, 0.6, 0.02
    x = np.linspace(0.05, 0.95, 181)
    u = sine_basis(x, 1024) @ square_pulse(start, end, width, 1024)
    expected = ndtr((x - start) / width) - ndtr((x - end) / width)
    np.testing.assert_allclose(u, expected, atol=1e-9)


@pytest.mark.parametrize("sigma", [0.0, 0.02])
def test_pluck_series_is_the_closed_form(sigma: float) -> None:
    problem = make_problem("string-plucked", {"height": "1", "x0": "0.35", "smoothing": str(sigma)})
    assert isinstance(problem, StringPlucked)
    x = np.linspace(0.0, 1.0, 201)
    u = sine_basis(x, 4096) @ pluck(0.35, 4096, sigma)
    tail = 2.0 / (np.pi**2 * 0.35 * 0.65 * 4096)  # the kink's series converges like 1/N
    np.testing.assert_allclose(u, pluck_extension(problem, x), atol=1e-12 if sigma else tail)


@pytest.mark.parametrize("family", FAMILIES)
def test_each_start_has_its_drawn_nonlinearity(family: str) -> None:
    spec = DatasetSpec(velocity_fraction=1.0)
    for index in range(3):
        state = initial_state(spec, family, "train", index)
        eps = float(spec.string.nonlinearity(state.q0, state.p0))
        assert eps == pytest.approx(state.nonlinearity, rel=1e-10)
        assert 1e-3 <= state.nonlinearity <= 1.0
        assert state.has_velocity and np.any(state.p0 != 0.0)
    at_rest = initial_state(DatasetSpec(velocity_fraction=0.0), family, "train", 0)
    assert not at_rest.has_velocity and np.all(at_rest.p0 == 0.0)


def test_files_hold_snapshots_and_their_generator(tmp_path: Path) -> None:
    paths = write_datasets(SMALL, tmp_path)
    assert sorted(paths) == sorted(SPLITS)
    train = _read(paths["train"])
    assert train["u"].shape == train["u_t"].shape == (6, 21, 128)
    np.testing.assert_allclose(train["x"], np.arange(1, 129) / 129)
    np.testing.assert_allclose(train["t"], np.arange(21) * 0.01)
    assert list(train["family"]) == ["square", "square", "noise", "noise", "pluck", "pluck"]
    assert str(train["split"]) == "train"
    parameters = json.loads(str(train["parameters"]))
    assert parameters["seed"] == 0 and parameters["k"] == 100.0 and parameters["dt"] == 0.01
    assert parameters["counts"] == {"train": 2, "validation": 1, "test": 1}
    assert parameters["shapes"]["square_width"] == 0.02
    assert np.all(train["energy_drift"] < 1e-9)
    start = train["q0"] @ sine_basis(train["x"], 128).T
    np.testing.assert_allclose(train["u"][:, 0], start, atol=1e-14 * np.abs(start).max())
    assert json.loads(str(train["shape"][0]))["width"] == 0.02
    # Split by shape: no initial state appears in two files.
    starts = {split: _read(path)["q0"] for split, path in paths.items()}
    for a in SPLITS:
        for b in SPLITS:
            if a < b:
                assert not np.any(np.all(starts[a][:, None] == starts[b][None], axis=2))


@pytest.mark.slow
def test_datasets_are_deterministic_by_seed(tmp_path: Path) -> None:
    first = _read(write_datasets(SMALL, tmp_path / "a")["train"])
    again = _read(write_datasets(SMALL, tmp_path / "b")["train"])
    parallel = _read(write_datasets(SMALL, tmp_path / "p", jobs=2)["train"])
    for key, value in first.items():
        np.testing.assert_array_equal(value, again[key])
        np.testing.assert_array_equal(value, parallel[key])
    other = DatasetSpec(seed=1, counts=(2, 0, 0), steps=20, families=SMALL.families)
    reseeded = _read(write_datasets(other, tmp_path / "c")["train"])
    assert not np.array_equal(first["u"], reseeded["u"])
    # A trajectory does not depend on how many were asked for.
    more = DatasetSpec(counts=(3, 0, 0), steps=20, families=("square",))
    larger = _read(write_datasets(more, tmp_path / "d")["train"])
    np.testing.assert_array_equal(larger["u"][:2], first["u"][:2])


def test_bad_specs_are_user_errors() -> None:
    with pytest.raises(DatasetError, match="families"):
        DatasetSpec(families=("triangle",))
    with pytest.raises(DatasetError, match="nonlinearity"):
        DatasetSpec(nonlinearity=(0.5, 0.1))
    with pytest.raises(DatasetError, match="counts"):
        DatasetSpec(counts=(0, 0, 0))


def test_command_writes_the_splits(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "data"
    args = ["--out", str(out), "--train", "1", "--validation", "1", "--test", "1"]
    code = main(["data", "koopman-string", *args, "--steps", "5", "--families", "sine,noise"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert sorted(p.name for p in out.iterdir()) == ["test.npz", "train.npz", "validation.npz"]
    assert "wrote train.npz (2)" in captured.out
    # Not a terminal: one progress line per family and split, no carriage returns.
    lines = captured.err.strip().splitlines()
    assert len(lines) == 6 and "\r" not in captured.err
    assert lines[0].startswith("koopman-string: train sine done (1/6")


NONE_AT_ALL = ["--train", "0", "--validation", "0", "--test", "0"]


@pytest.mark.parametrize(
    "argv",
    [
        ["data"],
        ["data", "koopman-string"],
        ["data", "koopman-string", "--out", "x", "--families", "triangle"],
        ["data", "koopman-string", "--out", "x", "--velocity-fraction", "2"],
        ["data", "koopman-string", "--out", "x", "--steps", "0"],
        ["data", "koopman-string", "--out", "x", *NONE_AT_ALL],
    ],
)
def test_command_rejects_bad_flags(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        raise SystemExit(main(argv))
    assert exit_info.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_progress_is_a_bar_on_a_terminal() -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    stream = Terminal()
    progress = _Progress(stream, 0.0)
    progress(1, 4, "train sine")
    progress(4, 4, "test sine")
    progress.close()
    text = stream.getvalue()
    assert text.count("\r") == 2 and text.endswith("\n") and "4/4" in text


@pytest.mark.slow
def test_the_datasets_on_a_local_ray_are_the_same_bytes(tmp_path: Path) -> None:
    """`membrane data ... --executor ray`: the trajectories as Ray tasks (a real local Ray of
    2 workers, loopback only), the files' arrays equal to the serial run's."""
    args = ["--train", "2", "--validation", "0", "--test", "1", "--steps", "10",
            "--families", "square,noise", "--no-progress"]  # fmt: skip
    assert main(["data", "koopman-string", "--out", str(tmp_path / "serial"), *args]) == 0
    on_ray = ["--executor", "ray", "--workers", "2"]
    assert main(["data", "koopman-string", "--out", str(tmp_path / "ray"), *args, *on_ray]) == 0
    for split in ("train", "test"):
        serial = _read(tmp_path / "serial" / f"{split}.npz")
        remote = _read(tmp_path / "ray" / f"{split}.npz")
        assert serial.keys() == remote.keys()
        for key, value in serial.items():
            np.testing.assert_array_equal(value, remote[key], err_msg=f"{split}: {key}")


def test_jobs_and_ray_together_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["data", "koopman-string", "--out", str(tmp_path), "--jobs", "2",
                 "--executor", "ray"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "--jobs is a local process pool" in err, err
