"""The exact evaluator's memory counts against the scene's budget (``table_max_bytes``).

The attack (docs/ROBUSTNESS.md): ``on_points`` built (points x modes) dense arrays, so the
``membrane`` scene at 256 x 256 peaked at 1.5 GiB, a corner force at 128 x 128 at 4.7 GiB, and a
65,536-point string with c = 1e-4 asked for 31.7 GiB, a MemoryError traceback at load.

Those three builds run in a child process whose address space is capped (``RLIMIT_AS``: its
size after imports plus 1 GiB), so that code like the old one fails there without taking this
machine's memory; the child reports tracemalloc's peak (numpy's allocations are traced) and what
``describe`` says. The peak must stay within the budget plus ``SLACK``: the fixed scratch blocks
(sine sums, the Duhamel table's build, the sine transform's buffers) and the lattice itself.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from typing import Any

import numpy as np
import pytest

from membrane_models import sines
from membrane_models.exact import MemoryBudgetExceeded, exact_solution
from membrane_models.exact.forced import ForcedModalSolution
from membrane_models.problems import make_problem
from membrane_server.evaluators import ExactEvaluator, TableEvaluator, build_evaluator
from membrane_server.scene import DEFAULT_TABLE_MAX_BYTES, SceneError, scene_from_dict
from membrane_server.source import resolve_source

MiB = 2**20
SLACK = 32 * MiB
CORNER = {"x0": "0.999", "y0": "0.001"}

# Runs in the child: builds one evaluator under an address-space cap, prints a JSON report.
_CHILD = textwrap.dedent(
    """
    import json, resource, sys, tracemalloc
    from pathlib import Path

    import numpy as np

    from membrane_models.problems import make_problem
    from membrane_server.evaluators import ExactEvaluator, TableEvaluator, build_evaluator
    from membrane_server.scene import SceneError, scene_from_dict
    from membrane_server.source import resolve_source

    spec = json.loads(sys.argv[1])
    status = Path("/proc/self/status").read_text().splitlines()
    size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize"))
    resource.setrlimit(resource.RLIMIT_AS, (size + 2**30, size + 2**30))
    if spec.get("scatter"):
        points = np.random.default_rng(0).random((spec["scatter"], 2))
    else:
        axes = [np.linspace(0.0, 1.0, n) for n in spec["lattice"]]
        points = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    problem = make_problem(spec["problem"], spec.get("overrides", {}))
    report = {}
    tracemalloc.start()
    try:
        if spec.get("scene"):
            nx, ny = spec["lattice"]
            scene = scene_from_dict({
                "name": "attack", "model": spec["problem"], "evaluator": "exact",
                "lattice": {"nx": nx, "ny": ny}, "dt": 0.01, "duration": 1.0,
            })
            evaluator = build_evaluator(scene, resolve_source(scene))
        else:
            budget = {"max_bytes": spec["max_bytes"]} if "max_bytes" in spec else {}
            evaluator = ExactEvaluator(problem, points, 0.01, 100, **budget)
        report["frame_finite"] = bool(np.isfinite(evaluator.frame(0.505)).all())
        report["info"] = evaluator.info()
    except SceneError as exc:
        report["scene_error"] = str(exc)
    except MemoryError as exc:
        report["memory_error"] = str(exc)
    report["peak"] = tracemalloc.get_traced_memory()[1]
    print(json.dumps(report))
    """
)


def _build_in_child(**spec: Any) -> dict[str, Any]:
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, json.dumps(spec)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    report: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return report


ATTACKS: dict[str, dict[str, Any]] = {
    "membrane-scene-256x256": {"problem": "membrane-forced", "lattice": [256, 256], "scene": True},
    "corner-force-128x128": {
        "problem": "membrane-forced", "overrides": CORNER, "lattice": [128, 128],
    },
    "string-65536-c-1e-4": {
        "problem": "string-forced", "overrides": {"C": "1e-4"}, "lattice": [65536],
    },
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("case", list(ATTACKS))
def test_the_attacks_build_within_the_scene_budget(case: str) -> None:
    report = _build_in_child(**ATTACKS[case])
    assert "memory_error" not in report and "scene_error" not in report, report
    info = report["info"]
    assert report["frame_finite"]
    assert info["max_bytes"] == DEFAULT_TABLE_MAX_BYTES
    # Everything counted fits the budget, all 101 frames included; the basis is not dense.
    assert info["memory_bytes"] <= DEFAULT_TABLE_MAX_BYTES
    assert info["precomputed_frames"] == 101
    assert info["spatial_method"] == "grid"
    # What was allocated stays within the budget, and within what describe reports, plus the
    # fixed scratch.
    assert report["peak"] <= DEFAULT_TABLE_MAX_BYTES + SLACK
    assert report["peak"] <= info["memory_bytes"] + SLACK


@pytest.mark.slow
def test_scattered_points_over_budget_are_refused_with_the_figure() -> None:
    """65,536 points off any grid, 1,039 per-frame modes: a dense basis needs 545 MB, and
    recomputing it would take 136 million sines a frame. A one-line SceneError, not a crash."""
    report = _build_in_child(problem="membrane-forced", scatter=65536)
    assert "memory_error" not in report, report
    message = report["scene_error"]
    assert "\n" not in message
    assert message.startswith("table_max_bytes: the exact evaluator of membrane-forced on 65536")
    dense = 8 * 65536 * (1039 + 1)
    assert f"needs {dense} bytes, more than the limit {DEFAULT_TABLE_MAX_BYTES}" in message
    assert report["peak"] <= DEFAULT_TABLE_MAX_BYTES + SLACK


@pytest.mark.slow
def test_a_series_over_budget_is_refused_before_its_table_is_built() -> None:
    """The corner force's Duhamel table is 128 MiB: refused under a 64 MiB budget, naming it."""
    report = _build_in_child(
        problem="membrane-forced", overrides=CORNER, lattice=[16, 16], max_bytes=64 * MiB
    )
    assert "memory_error" not in report, report
    message = report["scene_error"]
    assert "the series (65536 modes, a Duhamel table for 12581 of them) needs" in message
    needed = int(message.split(" needs ")[1].split()[0])
    assert 128 * MiB < needed < 160 * MiB
    assert message.endswith(f"more than the limit {64 * MiB}")
    assert report["peak"] <= 64 * MiB + SLACK  # refused before the table, not after


@pytest.mark.slow
def test_the_solver_bounds_its_own_temporaries() -> None:
    """A fast, sharp force (c = 100, k = 1e5): the first pass alone used to ask for a 4.6 GiB
    table. Now the series is built within the default budget, and a small budget refuses the
    mode selection up front (its figure named) instead of allocating it."""
    report = _build_in_child(
        problem="membrane-forced", overrides={"C": "100", "k": "1e5"}, lattice=[8, 8]
    )
    assert "memory_error" not in report and "scene_error" not in report, report
    # The first pass holds a table of up to 128 MiB for a moment (checked against the budget
    # like the final one), so the peak is bounded by the budget, not by what is held after.
    assert report["peak"] <= DEFAULT_TABLE_MAX_BYTES + SLACK
    with pytest.raises(MemoryBudgetExceeded, match=r"choosing modes among \d+ candidates needs"):
        exact_solution(make_problem("membrane-forced", CORNER), max_bytes=16 * MiB)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("problem", "overrides"),
    [("membrane-forced", {}), ("membrane-forced", CORNER), ("string-forced", {"C": "1e-4"})],
)
def test_the_series_states_its_memory_before_building(
    problem: str, overrides: dict[str, str]
) -> None:
    solution = exact_solution(make_problem(problem, overrides))
    assert isinstance(solution, ForcedModalSolution)
    predicted = ForcedModalSolution.bytes_needed(
        solution.problem, solution.modes, solution.quasi_static
    )
    assert predicted == solution.memory_bytes > 0


# -- the forms that replace the dense basis give the same numbers --------------------------------


def _reference(
    problem: str, overrides: dict[str, str], points: np.ndarray, times: tuple[float, ...]
) -> np.ndarray:
    """The exact solution at ``points`` (n, d) and ``times``: (n, nt)."""
    values: np.ndarray = exact_solution(make_problem(problem, overrides)).at_points(points, times)
    return values


def _grid(*counts: int) -> np.ndarray:
    axes = [np.linspace(0.0, 1.0, n) for n in counts]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("problem", "overrides", "counts"),
    [
        ("membrane-forced", {}, (64, 65)),  # dense basis 35 MB: the sine transform instead
        ("membrane-forced", CORNER, (33, 40)),
        ("string-forced", {"C": "1e-3"}, (4097,)),  # 19,304 per-frame modes
    ],
)
def test_grid_frames_equal_the_exact_solution(
    problem: str, overrides: dict[str, str], counts: tuple[int, ...]
) -> None:
    points = _grid(*counts)
    evaluator = ExactEvaluator(make_problem(problem, overrides), points, 0.05, 20)
    assert evaluator.info()["spatial_method"] == "grid"
    sample = slice(None, None, 37)  # the reference at every 37th point (it is slow)
    times = (0.05, 0.37, 0.5, 1.0, 1.3)  # on the grid, off it, past the force
    expected = _reference(problem, overrides, points[sample], times)
    scale = float(np.abs(expected).max())  # rounding is relative to the solution's size
    assert scale > 0
    for column, t in enumerate(times):
        served = evaluator.frame(t)[sample]
        np.testing.assert_allclose(served, expected[:, column], rtol=0, atol=1e-12 * scale)
    edges = evaluator.frame(0.5).reshape(counts)
    assert np.all(edges[0] == 0.0) and np.all(edges[-1] == 0.0)  # fixed ends, exactly


def test_chunked_frames_equal_the_exact_solution(monkeypatch: pytest.MonkeyPatch) -> None:
    """Scattered points whose dense basis does not fit: the basis is recomputed in blocks (made
    small here) per frame; served frames, precomputed and on demand, are the exact solution."""
    monkeypatch.setattr(sines, "_CHUNK_ELEMENTS", 2**12)
    monkeypatch.setattr("membrane_server.evaluators.EXACT_WORKING_FLOOR_BYTES", 0)
    problem = make_problem("membrane-forced")
    points = np.random.default_rng(1).random((300, 2))
    series = exact_solution(problem).memory_bytes
    dense = 8 * 300 * 1040
    evaluator = ExactEvaluator(problem, points, 0.05, 20, max_bytes=series + dense // 2)
    info = evaluator.info()
    assert info["spatial_method"] == "chunked" and info["precomputed_frames"] == 21
    assert info["memory_bytes"] <= series + dense // 2
    times = (0.25, 0.5, 0.77, 1.4)  # two precomputed steps, two computed on demand
    expected = _reference("membrane-forced", {}, points, times)
    scale = float(np.abs(expected).max())
    for column, t in enumerate(times):
        served = evaluator.frame(t)
        np.testing.assert_allclose(served, expected[:, column], rtol=0, atol=1e-12 * scale)


def test_describe_reports_the_memory_used() -> None:
    scene = scene_from_dict(
        {"name": "m", "model": "membrane-forced", "evaluator": "exact",
         "lattice": {"nx": 20, "ny": 20}, "dt": 0.01, "duration": 1.0}
    )  # fmt: skip
    info = build_evaluator(scene, resolve_source(scene)).info()
    frames = 101 * 400 * 8
    assert info["spatial_method"] == "dense"  # small: the cached basis, as before
    assert info["working_bytes"] > 400 * 1039 * 8  # the basis, the series' table
    assert info["memory_bytes"] == info["working_bytes"] + frames
    assert info["max_bytes"] == DEFAULT_TABLE_MAX_BYTES


def test_a_table_of_the_exact_solution_counts_its_source() -> None:
    """Frames of 323,200 bytes fit 1 MB, but not with the series and basis that compute them
    (a table of the exact solution, as ``membrane tradeoff`` serves the bare problem)."""
    problem, points = make_problem("membrane-forced"), _grid(20, 20)
    table = TableEvaluator(ExactEvaluator(problem, points), 0.01, 100, DEFAULT_TABLE_MAX_BYTES)
    info = table.info()
    assert info["memory_bytes"] == 101 * 400 * 8
    assert info["source_memory_bytes"] > 400 * 1039 * 8  # the series and its dense basis
    with pytest.raises(SceneError, match=r"needs 323200 bytes \(and \d+ for its source\)"):
        TableEvaluator(ExactEvaluator(problem, points), 0.01, 100, 1_000_000)
