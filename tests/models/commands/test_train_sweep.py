"""`membrane train --seeds / --sweep` on an executor: a sweep's runs in order, each in its own
folder, the same final losses to the last digit on a real local Ray (2 workers, loopback only)
as one after another here; bad sweep options are one line and exit code 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from membrane_cli.dispatcher import main
from membrane_errors import UserError
from membrane_models.executors import Job, RayExecutor, SerialExecutor

ITERATIONS = "12"


def _sweep(tmp_path: Path, name: str, *extra: str) -> dict:
    out = tmp_path / name
    code = main(["train", "string-forced", "--out", str(out), "--iterations", ITERATIONS,
                 "--no-progress", *extra])  # fmt: skip
    assert code == 0
    return json.loads((out / "sweep.json").read_text())


def _square(x: int) -> int:
    return x * x


def test_the_serial_executor_runs_jobs_in_order() -> None:
    jobs = [Job(f"j{k}", _square, (k,)) for k in range(5)]
    assert SerialExecutor().run(jobs, progress=False) == [0, 1, 4, 9, 16]


@pytest.mark.slow
def test_a_jobs_one_line_refusal_comes_back_from_ray_as_it_would_serially() -> None:
    from membrane_server.cache_build import parse_vary  # a job's function Ray's workers import

    jobs = [Job("fine", parse_vary, ("tissue.E=1",)), Job("bad", parse_vary, ("nope",))]
    said = r"^--vary takes KEY=V1,V2,\.\.\. \(e\.g\. tissue\.thickness=0\.002,0\.003\), got 'nope'$"
    with pytest.raises(UserError, match=said):
        SerialExecutor().run(jobs, progress=False)
    with pytest.raises(UserError, match=said):
        RayExecutor(workers=1).run(jobs, progress=False)


@pytest.mark.slow
def test_a_sweep_of_seeds_and_a_parameter_runs_each_in_its_folder(tmp_path: Path) -> None:
    summary = _sweep(tmp_path, "serial", "--seeds", "0,1", "--sweep", "c=4,6")
    names = [run["name"] for run in summary["runs"]]
    assert names == ["c=4,seed-0", "c=4,seed-1", "c=6,seed-0", "c=6,seed-1"]
    for run in summary["runs"]:
        assert run["iterations"] == int(ITERATIONS) and run["final"]["residual"] > 0
        assert (tmp_path / "serial" / run["name"] / "checkpoint.pt").exists()
    finals = [run["final"]["residual"] for run in summary["runs"]]
    assert len(set(finals)) == 4  # each seed and parameter trained its own network


@pytest.mark.slow
def test_a_sweep_on_a_local_ray_gives_the_serial_runs_losses_to_the_last_digit(
    tmp_path: Path,
) -> None:
    serial = _sweep(tmp_path, "serial", "--seeds", "0,1")
    on_ray = _sweep(tmp_path, "ray", "--seeds", "0,1", "--executor", "ray", "--workers", "2")
    assert on_ray["executor"] == "ray" and serial["executor"] == "serial"
    assert [r["name"] for r in on_ray["runs"]] == ["seed-0", "seed-1"]
    assert [r["final"] for r in on_ray["runs"]] == [r["final"] for r in serial["runs"]]
    assert on_ray["runs"][0]["final"] != on_ray["runs"][1]["final"]


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--seeds", "a,b"], "--seeds takes integers"),
        (["--seeds", "1,1"], "distinct seeds"),
        (["--sweep", "c"], "--sweep takes NAME=V1,V2"),
        (["--seeds", "0,1", "--resume"], "for a single run, not a sweep"),
        (["--executor", "ray"], "are for sweeps"),
        (["--seeds", "0", "--workers", "2"], "--workers is for --executor ray"),
        (["--seeds", "0", "--executor", "serial", "--ray-address", "x"], "is for --executor ray"),
        (["--seeds", "0", "--executor", "ray", "--workers", "0"], "--workers must be >= 1"),
        (["--seeds", "0", "--sweep", "nope=1,2"], "nope"),
    ],
)
def test_bad_sweep_options_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], says: str
) -> None:
    code = main(["train", "string-forced", "--out", str(tmp_path / "x"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and says in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x" / "sweep.json").exists()


def test_without_ray_installed_the_ray_executor_says_which_extra(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from membrane_errors import UserError

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(UserError, match=r"pip install 'membrane-tissue\[cluster\]'"):
        RayExecutor(workers=1).run([Job("j", _square, (2,))], progress=False)
