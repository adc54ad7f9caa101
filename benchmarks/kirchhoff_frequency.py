"""The Kirchhoff-Carrier string's frequency against amplitude, and what a linear model misses.

Left: one sine mode's angular frequency over its linear one against the mode's amplitude
(c = 1, k = 100, the datasets' string): the closed form (a Duffing oscillator, complete elliptic
integral) as lines, the modal solver's measured periods as markers. Right: the middle of a
smoothed pluck at nonlinearity 1 against the same pluck on the linear string (k = 0).

    python benchmarks/kirchhoff_frequency.py [--out docs/kirchhoff-frequency.png]

Prints the measured and closed-form ratios as a markdown table.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.exact.kirchhoff_carrier import (
    KirchhoffString,
    frequency_ratio,
    solve_kirchhoff,
)
from membrane_models.problems.string_shapes import pluck

FloatArray = NDArray[np.float64]

STRING = KirchhoffString(c=1.0, k=100.0)
MODES = (1, 2, 3)
MEASURED_EPS = (0.01, 0.1, 0.25, 0.5, 0.75, 1.0)


def amplitude_at(eps: FloatArray | float, mode: int) -> FloatArray:
    """Mode ``mode``'s amplitude at nonlinearity eps: k (n pi)^2 A^2 / (2 c^2) = eps."""
    return np.asarray(np.sqrt(2.0 * np.asarray(eps) * STRING.c**2 / STRING.k) / (mode * math.pi))


def measured_ratio(eps: float, mode: int) -> float:
    """The solver's frequency: from rest, q = A cn(...) first crosses zero at a quarter period."""
    q0 = np.zeros(mode)
    q0[-1] = float(amplitude_at(eps, mode))
    linear_period = 2.0 / (mode * STRING.c)
    t = np.linspace(0.0, 0.5 * linear_period, 20001)
    q = solve_kirchhoff(STRING, q0, np.zeros(mode), t).q[:, -1]
    i = int(np.flatnonzero(np.sign(q[1:]) != np.sign(q[:-1]))[0])
    crossing = t[i] - q[i] * (t[i + 1] - t[i]) / (q[i + 1] - q[i])
    return linear_period / (4.0 * crossing)


def pluck_traces(t: FloatArray, eps: float = 1.0) -> tuple[FloatArray, FloatArray, float]:
    """u(0.5, t) for a smoothed pluck (apex 0.3) at nonlinearity eps, and on the linear string."""
    shape = pluck(0.3, 128, 0.02)
    stretch = float(STRING.stretch(shape))
    height = math.sqrt(eps * STRING.c**2 / (STRING.k * stretch))  # at rest, S* = S(u0)
    q0, p0 = height * shape, np.zeros(128)
    middle = np.array([0.5])
    nonlinear = solve_kirchhoff(STRING, q0, p0, t).at_points(middle)[0][:, 0]
    linear = solve_kirchhoff(KirchhoffString(STRING.c, 0.0), q0, p0, t).at_points(middle)[0][:, 0]
    return nonlinear, linear, height


def draw(out: Path) -> list[tuple[int, float, float, float]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (left, right) = plt.subplots(1, 2, figsize=(11.0, 4.2))
    rows = _frequency_panel(left)
    t = np.linspace(0.0, 6.0, 1201)
    nonlinear, linear, height = pluck_traces(t)
    right.plot(t, linear / height, color="0.6", label="linear string (k = 0)")
    right.plot(t, nonlinear / height, color="C3", label="Kirchhoff-Carrier, k S*/c² = 1")
    right.set_xlabel("t (linear period of mode 1: 2)")
    right.set_ylabel("u(0.5, t) / pluck height")
    right.set_title("smoothed pluck (apex 0.3, smoothing s.d. 0.02)")
    right.legend(loc="lower left", fontsize=8)
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return rows


def _frequency_panel(axis: Any) -> list[tuple[int, float, float, float]]:
    eps = np.linspace(0.0, 1.0, 201)
    rows = []
    for mode in MODES:
        color = f"C{mode - 1}"
        axis.plot(amplitude_at(eps, mode), frequency_ratio(eps), color=color,
                  label=f"mode {mode}, closed form")  # fmt: skip
        measured = [measured_ratio(e, mode) for e in MEASURED_EPS]
        amplitudes = amplitude_at(np.array(MEASURED_EPS), mode)
        axis.plot(amplitudes, measured, "o", color=color, markersize=4,
                  label=f"mode {mode}, modal solver")  # fmt: skip
        rows += [
            (mode, e, m, float(frequency_ratio(e)))
            for e, m in zip(MEASURED_EPS, measured, strict=True)
        ]
    axis.axhline(1.0, color="0.6", linestyle=":", label="linear string")
    axis.set_xlabel("mode amplitude (string length 1)")
    axis.set_ylabel("ω / ω_linear")
    axis.set_title("frequency against amplitude (c = 1, k = 100; k S*/c² from 0 to 1)")
    axis.set_ylim(0.98, 1.45)  # room above the curves for the legend
    axis.legend(fontsize=7, ncol=2, loc="upper right")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description="The Kirchhoff-Carrier string's frequency figure.")
    parser.add_argument("--out", type=Path, default=Path("docs/kirchhoff-frequency.png"))
    args = parser.parse_args()
    rows = draw(args.out)
    print("| mode | k S*/c^2 | measured w/w0 | closed form | difference |")
    print("| --- | --- | --- | --- | --- |")
    for mode, eps, measured, exact in rows:
        print(f"| {mode} | {eps:g} | {measured:.6f} | {exact:.6f} | {measured - exact:.1e} |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
