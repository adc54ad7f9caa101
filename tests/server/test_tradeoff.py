"""The trade-off tool: a real server process, a real client, errors against the exact solution."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from membrane_cli.dispatcher import main
from membrane_server.tradeoff import (
    LATTICES,
    Case,
    Measurement,
    measure_cases,
    pareto_front,
    plan_cases,
)
from membrane_server.tradeoff_report import markdown_report

if TYPE_CHECKING:
    from onnx_graphs import TestModel


def test_quick_plan_without_models_has_the_exact_reference_on_the_smallest_lattices(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr("membrane_server.tradeoff.list_models", lambda: [])
    cases = plan_cases(quick=True)
    assert {(c.scene, c.lattice, c.evaluator) for c in cases} == {
        (scene, LATTICES[scene][0], kind)
        for scene in ("rope", "rope-plucked", "membrane")
        for kind in ("exact", "table")
    }
    assert all(c.knobs == "-" for c in cases)


def test_full_plan_covers_every_lattice_and_the_series_tolerance(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr("membrane_server.tradeoff.list_models", lambda: [])
    cases = plan_cases(["membrane", "rope-plucked"])
    assert {c.lattice for c in cases if c.scene == "membrane"} == {(5, 5), (20, 20), (100, 100)}
    per_query = {(c.scene, c.rtol) for c in cases if c.on_demand}
    # The forced membrane is a truncated series; the plucked string is a closed form.
    assert per_query == {
        ("membrane", None),
        ("membrane", 1e-3),
        ("membrane", 1e-6),
        ("rope-plucked", None),
    }


def test_unknown_scene_is_a_usage_error(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    argv = ["tradeoff", "--scene", "trampoline", "--no-plot", "--out", str(tmp_path / "T.md")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "trampoline" in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_measures_models_knobs_and_keeps_cases_that_cannot_be_served(
    test_models: dict[str, TestModel],
) -> None:
    model = str(test_models["membrane"].manifest_path)
    cases = [
        Case("membrane", model, "separable", (5, 5)),
        Case("membrane", model, "network", (5, 5), optimization="disabled"),
        Case("membrane", model, "separable", (5, 5), threads=2),
        Case("membrane", "no-such-model", "network", (5, 5)),
        Case("membrane", None, "exact", (5, 5), rtol=1e-3, on_demand=True),
        Case("membrane", None, "table", (5, 5)),
    ]
    separable, network, threaded, missing, truncated, table = measure_cases(cases, rounds=2)
    for m in (separable, network, threaded, truncated, table):
        assert m.ok, m.failure
        assert m.samples == 101  # one timed sweep of the scene's 101 steps
        assert 0 < m.p50_us <= m.p99_us
    # The same network three ways: the same frames, so the same error against the exact solution.
    assert network.relative_l2 == pytest.approx(separable.relative_l2, rel=1e-5)
    assert threaded.relative_l2 == pytest.approx(separable.relative_l2, rel=1e-9)
    assert separable.relative_l2 > 1e-2  # untrained: nowhere near the solution
    assert network.evaluator_info["kind"] == "network"
    # The missing model is recorded with its reason; the sweep went on.
    assert not missing.ok and "no-such-model" in (missing.failure or "")
    # A series cut at 1e-3 is wrong by about that much; the table of the exact solution is not.
    assert 1e-6 < truncated.relative_l2 < 1e-2
    assert truncated.evaluator_info["modes"] > 0
    assert table.relative_l2 < 1e-6
    info = table.evaluator_info
    assert (info["kind"], info["source"], info["frames"]) == ("table", "exact", 101)
    assert info["memory_bytes"] in (101 * 25 * 4, 101 * 25 * 8)  # float32 or float64 frames


@pytest.mark.slow
def test_quick_run_writes_the_table_and_the_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("membrane_server.tradeoff.list_models", lambda: [])  # the reference only
    out, plot = tmp_path / "docs" / "TRADEOFF.md", tmp_path / "docs" / "tradeoff.png"
    argv = ["tradeoff", "--quick", "--scene", "rope", "--rounds", "2"]
    assert main([*argv, "--out", str(out), "--plot", str(plot)]) == 0
    text = out.read_text()
    assert f"membrane tradeoff --out {out} --plot {plot} --quick --scene rope" in text
    assert "logical cores" in text  # the machine it ran on
    assert "![latency against error, log-log](tradeoff.png)" in text
    rows = [line for line in text.splitlines() if line.startswith("| 20 |")]
    assert len(rows) == 2
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        p50, p99, error = float(cells[4]), float(cells[5]), float(cells[6])
        assert 0 < p50 <= p99
        assert error < 1e-6  # the exact reference, up to float32 on the wire
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "2/2 cases measured" in capsys.readouterr().out


def _measured(p50: float, error: float, lattice: tuple[int, ...] = (20,)) -> Measurement:
    case = Case("rope", "m", "network", lattice)
    return Measurement(case, p50_us=p50, p99_us=2 * p50, relative_l2=error)


def test_pareto_front_keeps_only_cases_nothing_beats_on_both_axes() -> None:
    fast_rough, slow_exact = _measured(10, 1e-2), _measured(1000, 1e-8)
    dominated, middle = _measured(500, 1e-2), _measured(100, 1e-4)
    failed = Measurement(Case("rope", "m", "network", (20,)), failure="cannot")
    front = pareto_front([slow_exact, dominated, fast_rough, middle, failed])
    assert front == [fast_rough, middle, slow_exact]


@pytest.mark.slow
def test_report_lists_unmeasured_cases_and_says_when_no_model_is_shipped(tmp_path: Path) -> None:
    good = _measured(50, 1e-8)
    good.build_s = 0.1
    bad = Measurement(Case("rope", "m", "network", (20,)), failure="model has no such graph")
    text = markdown_report([good, bad], "membrane tradeoff", None, tmp_path / "T.md", 4, [])
    assert "none yet (only the exact reference is measured)" in text
    assert "## Not measured" in text and "model has no such graph" in text
    assert "| 20 | m | network | - | 50.0 | 100 | 1.00e-08 |" in text


def test_a_zoo_model_named_like_its_problem_is_served_by_path(
    monkeypatch: pytest.MonkeyPatch, test_models: dict[str, TestModel]
) -> None:
    """To the exact evaluator a problem name means the problem: models go by manifest path."""
    from membrane_models.artifacts.manifest import Manifest

    manifest = Manifest.read(test_models["string"].manifest_path)
    monkeypatch.setattr("membrane_server.tradeoff.resolve_model", lambda name: manifest)
    assert Case("rope", "string-forced", "network", (20,)).scene_data()["model"] == str(
        manifest.path
    )
    reference = Case("rope", None, "table", (20,))
    assert reference.scene_data()["model"] == "string-forced"
    assert reference.model_label == "exact reference"


def test_a_model_of_a_problem_variant_is_planned_on_its_problems_scene(
    monkeypatch: pytest.MonkeyPatch, test_models: dict[str, TestModel]
) -> None:
    from dataclasses import replace

    from membrane_models.artifacts.manifest import Manifest

    smooth = replace(
        Manifest.read(test_models["string"].manifest_path), problem="string-plucked-smooth"
    )
    monkeypatch.setattr("membrane_server.tradeoff.list_models", lambda: ["smooth-pluck"])
    monkeypatch.setattr("membrane_server.tradeoff.resolve_model", lambda name: smooth)
    cases = plan_cases(["rope", "rope-plucked"], quick=True)
    planned = {(c.scene, c.evaluator) for c in cases if c.model == "smooth-pluck"}
    assert planned == {("rope-plucked", kind) for kind in ("network", "separable", "table")}


@pytest.mark.slow
def test_accuracy_on_a_local_ray_is_the_serial_runs_to_the_last_digit(
    test_models: dict[str, TestModel],
) -> None:
    from membrane_models.executors import RayExecutor

    model = str(test_models["membrane"].manifest_path)
    cases = [
        Case("membrane", model, "separable", (5, 5)),
        Case("membrane", None, "exact", (5, 5), rtol=1e-3, on_demand=True),
        Case("membrane", "no-such-model", "network", (5, 5)),
    ]
    serial = measure_cases(cases, rounds=2)
    on_ray = measure_cases(cases, rounds=2, executor=RayExecutor(workers=2))
    assert [m.failure is None for m in on_ray] == [True, True, False]
    assert on_ray[2].failure == serial[2].failure and "no-such-model" in (on_ray[2].failure or "")
    for ray_case, serial_case in zip(on_ray[:2], serial[:2], strict=True):
        assert ray_case.relative_l2 == serial_case.relative_l2 > 1e-6
        assert ray_case.max_abs_error == serial_case.max_abs_error
        assert ray_case.samples == serial_case.samples == 101  # the timings: serial, as ever
