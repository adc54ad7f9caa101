"""`membrane exact`: the files it writes, and one-line errors with exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from membrane_cli.dispatcher import main


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["exact", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_string_forced_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s.npz"
    code, stdout, _ = _run(capsys, "string-forced", "--nx", "101", "--nt", "101", "--out", str(out))
    assert code == 0
    assert "max |u|" in stdout and "modes" in stdout and len(stdout.strip().splitlines()) == 1
    with np.load(out) as data:
        assert data["u"].shape == (101, 101)
        np.testing.assert_allclose(data["x"], np.linspace(0, 1, 101))
        np.testing.assert_allclose(data["t"], np.linspace(0, 1, 101))
        assert "y" not in data
        assert np.abs(data["u"]).max() == pytest.approx(5.6e-4, rel=0.02)
        assert str(data["problem"]) == "string-forced"
        assert json.loads(str(data["parameters"]))["c"] == 10.0
        assert int(data["n_modes"]) > 0 and float(data["truncation_error"]) <= 1e-10


@pytest.mark.slow
def test_membrane_forced_file_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, image = tmp_path / "m.npz", tmp_path / "m.png"
    code, _, err = _run(
        capsys,
        "membrane-forced",
        "--nx",
        "21",
        "--ny",
        "21",
        "--nt",
        "101",
        "--out",
        str(out),
        "--plot",
        str(image),
    )
    assert code == 0, err
    with np.load(out) as data:
        assert data["u"].shape == (21, 21, 101)
        assert data["y"].shape == (21,)
        assert np.abs(data["u"]).max() == pytest.approx(4.8e-4, rel=0.02)
    assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_overrides_reach_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "p.npz"
    code, _, _ = _run(
        capsys,
        "string-plucked",
        "--set",
        "C=2",
        "--set",
        "height=0.1",
        "--nx",
        "11",
        "--nt",
        "5",
        "--out",
        str(out),
        "--plot",
        str(tmp_path / "p.png"),
    )
    assert code == 0
    with np.load(out) as data:
        parameters = json.loads(str(data["parameters"]))
        assert parameters["c"] == 2.0 and parameters["height"] == 0.1
        assert data["u"].shape == (11, 5)
        assert np.abs(data["u"][:, 0]).max() == pytest.approx(0.1)
        np.testing.assert_allclose(data["t"], np.linspace(0, 2, 5))


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["membrane-forced", "--set", "C=-1"], "c must be > 0"),
        (["membrane-forced", "--set", "C"], "NAME=VALUE"),
        (["no-such-problem"], "unknown problem"),
        (["string-forced", "--nx", "1"], "--nx must be >= 2"),
        (["string-forced", "--nt", "0"], "--nt must be >= 2"),
        (["string-forced", "--ny", "11"], "--ny is only for 2-D"),
        (["string-forced", "--set", "x0=2"], "x0 must lie inside"),
        (["string-forced", "--set", "c=nan"], "finite"),
        (["string-forced", "--set", "zeta=1"], "no parameter"),
        (["string-forced", "--nx", "ten"], "invalid int"),
        (["string-forced", "--rtol", "-1"], "--rtol"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(
    argv: list[str], fragment: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bad.npz"
    try:
        code = main(["exact", *argv, "--out", str(out)])
    except SystemExit as exit_:  # argparse's own errors exit through the parser
        code = int(exit_.code or 0)
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert fragment in err
    assert "Traceback" not in err
    assert not out.exists()


def test_out_must_be_npz(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(capsys, "string-forced", "--out", str(tmp_path / "u.txt"))
    assert code == 2 and ".npz" in err


def test_unwritable_out_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(capsys, "string-forced", "--out", str(tmp_path / "missing" / "u.npz"))
    assert code == 2 and len(err.strip().splitlines()) == 1


def test_listed_in_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "exact" in capsys.readouterr().out
