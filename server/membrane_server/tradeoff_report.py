"""The trade-off's outputs: a markdown page with the tables, and a log-log Pareto plot."""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

from membrane_server.tradeoff import SCENE_PROBLEMS, Measurement, pareto_front

__all__ = ["ERROR_FLOOR", "machine_description", "markdown_report", "plot_tradeoff"]

# Errors below this are drawn at it (the log axis has no zero); the table shows the real value.
ERROR_FLOOR = 1e-9
_MARKERS = {"exact": "o", "table": "s", "separable": "^", "network": "D"}


def machine_description() -> str:
    """CPU model, core count, OS, Python and the libraries that set the figures."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = []
    for package in ("onnxruntime", "pyzmq", "numpy"):
        try:
            versions.append(f"{package} {metadata.version(package)}")
        except metadata.PackageNotFoundError:
            continue
    load = ""
    if hasattr(os, "getloadavg"):
        load = f", load average {os.getloadavg()[0]:.1f} at the end"
    return (
        f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()}, "
        f"Python {platform.python_version()}, {', '.join(versions)}{load}"
    )


def _latency(value: float) -> str:
    if math.isnan(value):
        return "-"
    return f"{value:.0f}" if value >= 100 else f"{value:.1f}"


def _error(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.2e}"


def _evaluator_label(m: Measurement) -> str:
    source = m.evaluator_info.get("source")
    return f"table ({source})" if m.case.evaluator == "table" and source else m.case.evaluator


def _scene_table(measurements: Sequence[Measurement]) -> list[str]:
    fronts = {
        lattice: {
            id(m) for m in pareto_front([x for x in measurements if x.case.lattice == lattice])
        }
        for lattice in {m.case.lattice for m in measurements}
    }
    lines = [
        "| lattice | model | evaluator | knobs | p50 us | p99 us | rel. L2 error | max abs error "
        "| build s | Pareto |",
        "| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | :---: |",
    ]
    ordered = sorted(
        (m for m in measurements if m.ok),
        key=lambda m: (math.prod(m.case.lattice), m.p50_us),
    )
    for m in ordered:
        star = "*" if id(m) in fronts[m.case.lattice] else ""
        lines.append(
            f"| {m.case.lattice_label} | {m.case.model_label} | {_evaluator_label(m)} | "
            f"{m.case.knobs} | {_latency(m.p50_us)} | {_latency(m.p99_us)} | "
            f"{_error(m.relative_l2)} | {_error(m.max_abs_error)} | {m.build_s:.2f} | {star} |"
        )
    return lines


def markdown_report(
    measurements: Sequence[Measurement],
    command: str,
    plot_path: Path | None,
    out_path: Path,
    rounds: int,
    zoo: Sequence[str],
) -> str:
    """The page: how it was measured, on what, then one table per scene."""
    stamp = time.strftime("%Y-%m-%d %H:%M %Z")
    shipped = ", ".join(zoo) if zoo else "none yet (only the exact reference is measured)"
    lines = [
        "# Speed/accuracy trade-off",
        "",
        "Every way the server can answer a query, measured end to end: a real server process and",
        f"a real `Client` sweeping the scene's whole time grid in order {rounds} times (the first",
        "sweep warms up and is not timed).",
        "",
        "- **Latency**: one `Client.query(t)` round trip (ZeroMQ + msgpack + the evaluator) as the",
        "  client sees it, p50 and p99 over the timed sweeps.",
        "- **Error**: relative L2 of the served frames against the exact solution on the same",
        "  lattice and time grid, ||u - u_exact|| / ||u_exact|| over all points and steps. Frames",
        "  travel as float32, so even the exact evaluator shows about 1e-8.",
        "- **Pareto**: `*` marks the cases that no other case on the same lattice beats on both",
        "  p50 latency and error (p50: a p99 over a few hundred queries on a shared machine",
        "  says more about the other processes than about the case).",
        "- **Knobs**, on the study's lattice size: onnxruntime intra-op threads and graph",
        "  optimisation level (`opt`); for the exact solution, computing each frame per query",
        "  (`per query`: what a time off the grid costs; otherwise the server precomputes the",
        "  frames of the time grid at load) and the series' truncation tolerance (`rtol`).",
        "- **build s**: time to build the evaluator at load (precomputed frames included).",
        "",
        "Each case is measured once, one after another. On a machine shared with other work,",
        "rerun before trusting a difference smaller than the run-to-run spread.",
        "",
        f"Regenerate (table and plot): `{command}`",
        "",
        f"Measured {stamp} on: {machine_description()}.",
        "",
        f"Shipped models at the time: {shipped}.",
        "",
    ]
    if plot_path is not None:
        relative = os.path.relpath(plot_path, out_path.parent)
        lines += [f"![latency against error, log-log]({relative})", ""]
    for scene, problem in SCENE_PROBLEMS.items():
        rows = [m for m in measurements if m.case.scene == scene]
        if not rows:
            continue
        lines += [f"## `{scene}` ({problem})", "", *_scene_table(rows), ""]
    failed = [m for m in measurements if not m.ok]
    if failed:
        lines += ["## Not measured", ""]
        for m in failed:
            case = m.case
            lines.append(
                f"- `{case.scene}` {case.lattice_label}, {m.case.model_label}, {case.evaluator} "
                f"({case.knobs}): {m.failure}"
            )
        lines.append("")
    return "\n".join(lines)


def plot_tradeoff(measurements: Sequence[Measurement], path: Path) -> None:
    """One log-log panel per scene: p50 latency (bar to p99) against error, Pareto per lattice."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    scenes = [s for s in SCENE_PROBLEMS if any(m.ok and m.case.scene == s for m in measurements)]
    figure, axes = plt.subplots(1, max(len(scenes), 1), figsize=(5.5 * max(len(scenes), 1), 4.8))
    panels = list(axes.flat) if hasattr(axes, "flat") else [axes]
    colours = plt.get_cmap("viridis")
    for panel, scene in zip(panels, scenes, strict=False):
        rows = [m for m in measurements if m.ok and m.case.scene == scene]
        lattices = sorted({m.case.lattice for m in rows}, key=math.prod)
        for index, lattice in enumerate(lattices):
            colour = colours(index / max(len(lattices) - 1, 1) * 0.85)
            group = [m for m in rows if m.case.lattice == lattice]
            for m in group:  # a faint bar from p50 to p99: how steady each case is
                error = max(m.relative_l2, ERROR_FLOOR)
                panel.plot([m.p50_us, m.p99_us], [error, error], color=colour, alpha=0.35, lw=1)
            for kind, marker in _MARKERS.items():
                points = [m for m in group if m.case.evaluator == kind]
                if points:
                    panel.scatter(
                        [m.p50_us for m in points],
                        [max(m.relative_l2, ERROR_FLOOR) for m in points],
                        marker=marker,
                        color=colour,
                        s=36,
                        label=f"{kind}" if index == 0 else None,
                    )
            front = pareto_front(group)
            panel.step(
                [m.p50_us for m in front],
                [max(m.relative_l2, ERROR_FLOOR) for m in front],
                where="post",
                color=colour,
                linewidth=1,
                label=f"lattice {'x'.join(map(str, lattice))}",
            )
        panel.set_xscale("log")
        panel.set_yscale("log")
        panel.xaxis.set_minor_formatter(NullFormatter())
        panel.yaxis.set_minor_formatter(NullFormatter())
        panel.set_xlabel("query latency (us), client round trip: p50 (bar to p99)")
        panel.set_ylabel("relative L2 error vs exact")
        panel.set_title(f"{scene} ({SCENE_PROBLEMS[scene]})")
        panel.grid(True, which="both", alpha=0.3)
        panel.legend(fontsize=7, loc="best")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
