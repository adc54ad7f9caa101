"""Measuring a stepping model of the nonlinear string on the test split: the error table.

A *rollout* takes the test trajectories' initial states (u, u_t) and returns u after each
requested number of steps; the Koopman graphs (``onnx_rollout``) are one, the baselines of
docs/KOOPMAN.md others. The reference is the test file's own snapshots up to its last step and
beyond it the Galerkin solver (``exact.kirchhoff_carrier``) run from the trajectory's modal
initial data, all 128 modes, DOP853 at its default tolerance.

The error of one trajectory after m steps is ||u_m - u_ref(m)|| / rms_j ||u_ref(j)||, the
norms over the 128 points and the rms over the file's snapshots: the motion's own displacement
scale, which a passing zero crossing of u_ref(m) does not blow up. A row is the mean over its
trajectories. Bands are by the nonlinearity eps = k S* / c^2 (``data.koopman``): ``linear``
below 0.01 (frequencies within 0.4% of the linear ones), ``weak`` to 0.1 (within 3.7%),
``strong`` from 0.1 to 1 (3.7% to 32%).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_errors import UserError
from membrane_models.artifacts.evaluate import onnx_session
from membrane_models.artifacts.koopman_manifest import KoopmanManifest
from membrane_models.exact.kirchhoff_carrier import KirchhoffString, solve_kirchhoff

__all__ = [
    "BANDS",
    "HORIZONS",
    "SMOOTH_FAMILIES",
    "Rollout",
    "TestSplit",
    "band_of",
    "error_table",
    "modal_energy",
    "onnx_rollout",
]

FloatArray = NDArray[np.float64]
# (initial states (n, 2 P), steps asked for, increasing) -> {step: u (n, P)}
Rollout = Callable[[FloatArray, Sequence[int]], dict[int, FloatArray]]

HORIZONS = (1, 10, 100, 1000)
BANDS = {"linear": (0.0, 0.01), "weak": (0.01, 0.1), "strong": (0.1, math.inf)}
# Smooth: the first 10 sine modes carry at least 98% of the stretch S = int u_x^2 dx (one mode
# m <= 8; the pluck smoothed over s.d. 0.02, 98-99%). Rough: the kinked pluck (94-97%), the
# square pulses (57-73%) and the noise (10-34%), measured on the default test split.
SMOOTH_FAMILIES = ("sine", "pluck-smooth")
LONG_RTOL = 1e-10


def band_of(nonlinearity: float) -> str:
    """The band of a trajectory's eps = k S* / c^2."""
    for name, (low, high) in BANDS.items():
        if low <= nonlinearity < high:
            return name
    raise ValueError(f"nonlinearity {nonlinearity} is in no band")


@dataclass
class TestSplit:
    __test__ = False  # not a pytest class, whatever its name
    """A dataset split's trajectories and their references (computed once, then kept)."""

    path: Path
    states: FloatArray  # (n, snapshots, 2 P)
    families: list[str]
    nonlinearity: FloatArray
    energy: FloatArray
    q0: FloatArray
    p0: FloatArray
    dt: float
    string: KirchhoffString
    _beyond: dict[int, FloatArray] = field(default_factory=dict)

    @classmethod
    def read(cls, path: Path) -> TestSplit:
        if not path.is_file():
            raise UserError(f"no dataset split at {path}")
        with np.load(path, allow_pickle=False) as data:
            parameters = json.loads(str(data["parameters"]))
            return cls(
                path=path,
                states=np.concatenate([data["u"], data["u_t"]], axis=2),
                families=[str(f) for f in data["family"]],
                nonlinearity=np.asarray(data["nonlinearity"], dtype=np.float64),
                energy=np.asarray(data["energy"], dtype=np.float64),
                q0=np.asarray(data["q0"]),
                p0=np.asarray(data["p0"]),
                dt=float(parameters["dt"]),
                string=KirchhoffString(float(parameters["c"]), float(parameters["k"])),
            )

    @property
    def points(self) -> int:
        return self.states.shape[2] // 2

    @property
    def bands(self) -> list[str]:
        return [band_of(float(e)) for e in self.nonlinearity]

    def scale(self) -> FloatArray:
        """Each trajectory's displacement scale: rms over the snapshots of ||u||."""
        u = self.states[:, :, : self.points]
        return np.asarray(np.sqrt(np.mean(np.sum(u * u, axis=2), axis=1)))

    def reference(self, step: int) -> FloatArray:
        """u_ref after ``step`` steps (n, P): the snapshots, or the Galerkin solver beyond."""
        if step < self.states.shape[1]:
            return np.asarray(self.states[:, step, : self.points])
        if step not in self._beyond:
            self._beyond[step] = self._cached(step)
        return self._beyond[step]

    def _cached(self, step: int) -> FloatArray:
        """The Galerkin references, kept beside the split (a minute for 30 trajectories to
        1000 steps; the kinked plucks' 128 modes cost most)."""
        cache = self.path.with_name(f"{self.path.stem}.reference-{step}.npy")
        if cache.is_file() and cache.stat().st_mtime >= self.path.stat().st_mtime:
            cached = np.load(cache, allow_pickle=False)
            if cached.shape == (self.states.shape[0], self.points):
                return np.asarray(cached)
        x = np.arange(1, self.points + 1) / (self.points + 1)
        rows = []
        for q0, p0 in zip(self.q0, self.p0, strict=True):
            solution = solve_kirchhoff(self.string, q0, p0, [step * self.dt])
            rows.append(solution.at_points(x)[0][0])
        result = np.asarray(rows)
        with contextlib.suppress(OSError):  # a read-only dataset: computed again next time
            np.save(cache, result)
        return result


def error_table(
    rollout: Rollout, split: TestSplit | Path, steps: Sequence[int] = HORIZONS
) -> dict[str, Any]:
    """Mean relative error per family and band (and overall rows) at each horizon."""
    test = split if isinstance(split, TestSplit) else TestSplit.read(split)
    ordered = sorted(steps)
    predicted = rollout(test.states[:, 0], ordered)
    scale = test.scale()
    per = {s: np.linalg.norm(predicted[s] - test.reference(s), axis=1) / scale for s in ordered}
    families, bands = np.array(test.families), np.array(test.bands)
    groups: list[tuple[str, str, NDArray[np.bool_]]] = []
    for family in dict.fromkeys(test.families):
        for band in BANDS:
            groups.append((family, band, (families == family) & (bands == band)))
    smooth = np.isin(families, SMOOTH_FAMILIES)
    for band in BANDS:
        groups.append(("smooth", band, smooth & (bands == band)))
        groups.append(("rough", band, ~smooth & (bands == band)))
    groups.append(("all", "all", np.ones(len(families), dtype=bool)))
    rows = [
        {
            "family": family,
            "band": band,
            "trajectories": int(mask.sum()),
            "errors": {str(s): float(np.mean(per[s][mask])) for s in ordered},
        }
        for family, band, mask in groups
        if mask.any()
    ]
    return {
        "metric": "mean over trajectories of ||u - u_ref|| / rms_t ||u_ref|| on the 128 points",
        "split": str(test.path.name),
        "steps": ordered,
        "bands": {
            name: [low, None if math.isinf(high) else high] for name, (low, high) in BANDS.items()
        },
        "smooth_families": list(SMOOTH_FAMILIES),
        "rows": rows,
    }


def modal_energy(
    states: FloatArray, string: KirchhoffString, modes: int | None = None
) -> FloatArray:
    """The string's energy of states (n, 2 P) of (u, u_t), from their discrete sine series
    (its first ``modes`` modes only, when given)."""
    points = states.shape[1] // 2
    x = np.arange(1, points + 1) / (points + 1)
    n = np.arange(1, (modes or points) + 1)
    project = 2.0 / (points + 1) * np.sin(np.pi * np.outer(x, n))  # (P, modes)
    q = states[:, :points] @ project
    p = states[:, points:] @ project
    return np.asarray(string.energy(q, p))


class _Graphs:
    """The three graphs, stepping a latent with an optional re-encoding every ``reencode``
    steps (decode, encode again: Fathi et al., ICLR 2024), which puts the latent back on the
    encoder's image of the states it decodes to."""

    def __init__(self, manifest: KoopmanManifest, reencode: int | None = None) -> None:
        if reencode is not None and reencode < 1:
            raise UserError(f"re-encoding takes a period of at least 1 step, not {reencode}")
        self.encoder = onnx_session(manifest.verify("encoder"))
        self.stepper = onnx_session(manifest.verify("step"))
        self.decoder = onnx_session(manifest.verify("decoder"))
        self.reencode = reencode

    def encode(self, states: FloatArray) -> Any:
        return self.encoder.run(None, {"state": states.astype(np.float32)})[0]

    def decode(self, z: Any) -> FloatArray:
        return np.asarray(self.decoder.run(None, {"z": z})[0], dtype=np.float64)

    def step(self, z: Any, k: int) -> Any:
        """The latent after step ``k`` (counted from 1) from ``z`` after step k - 1."""
        z = self.stepper.run(None, {"z": z})[0]
        if self.reencode is not None and k % self.reencode == 0:
            z = self.encoder.run(None, {"state": self.decoder.run(None, {"z": z})[0]})[0]
        return z


def onnx_rollout(manifest: KoopmanManifest, reencode: int | None = None) -> Rollout:
    """The Koopman graphs as a rollout: encode once, step, decode at the steps asked for
    (``reencode``: decode and encode again every that many steps)."""
    graphs = _Graphs(manifest, reencode)
    points = manifest.points

    def rollout(initial: FloatArray, steps: Sequence[int]) -> dict[int, FloatArray]:
        z = graphs.encode(initial)
        out: dict[int, FloatArray] = {}
        done = 0
        for target in sorted(steps):
            for k in range(done + 1, target + 1):
                z = graphs.step(z, k)
            done = target
            out[target] = graphs.decode(z)[:, :points]
        return out

    return rollout


def long_horizon(
    manifest: KoopmanManifest,
    test: TestSplit,
    steps: int,
    families: Sequence[str] = ("sine",),
    reencode: int | None = None,
) -> dict[str, Any]:
    """Decoded energy over ``steps`` steps (every trajectory) and the error at the end (those of
    ``families``, whose Galerkin references are cheap to run that far); ``reencode``: as
    ``onnx_rollout``'s."""
    graphs = _Graphs(manifest, reencode)
    z = graphs.encode(test.states[:, 0])
    low = np.full(len(test.families), np.inf)
    high = np.full(len(test.families), -np.inf)
    # What a state of the model's size can hold: the energy of the initial state's first
    # ``pairs`` modes (the rough shapes' energy lies largely above them).
    pairs = int(manifest.architecture.get("pairs", test.points))
    kept = modal_energy(test.states[:, 0], test.string, pairs)
    low_kept, high_kept = low.copy(), high.copy()
    every = max(steps // 100, 1)
    for k in range(1, steps + 1):
        z = graphs.step(z, k)
        if k % every == 0 or k == steps:
            energy = modal_energy(graphs.decode(z), test.string)
            low, high = (
                np.minimum(low, energy / test.energy),
                np.maximum(high, energy / test.energy),
            )
            low_kept = np.minimum(low_kept, energy / kept)
            high_kept = np.maximum(high_kept, energy / kept)
    final = graphs.decode(z)[:, : test.points]
    chosen = [i for i, f in enumerate(test.families) if f in families]
    x = np.arange(1, test.points + 1) / (test.points + 1)
    errors = []
    for i in chosen:
        # 10^5 steps: a looser tolerance than the tables' (the phase error it leaves, about
        # 1e-10 per unit time, is far below the model's).
        reference = solve_kirchhoff(
            test.string, test.q0[i], test.p0[i], [steps * test.dt], rtol=LONG_RTOL
        )
        u = reference.at_points(x)[0][0]
        errors.append(float(np.linalg.norm(final[i] - u) / test.scale()[i]))
    families_all = np.array(test.families)

    def by_family(lows: FloatArray, highs: FloatArray) -> dict[str, list[float]]:
        return {
            family: [
                float(lows[families_all == family].min()),
                float(highs[families_all == family].max()),
            ]
            for family in dict.fromkeys(test.families)
        }

    return {
        "steps": steps,
        **({} if reencode is None else {"reencode": reencode}),
        "energy_ratio_min": float(low.min()),
        "energy_ratio_max": float(high.max()),
        "energy_ratio_by_family": by_family(low, high),
        "energy_reference": "the test file's initial energy (all 128 modes; conserved)",
        "energy_ratio_to_kept_modes_by_family": by_family(low_kept, high_kept),
        "kept_modes": pairs,
        "energy_sampled_every": every,
        "error_families": list(families),
        "error_reference_rtol": LONG_RTOL,
        "error_mean": float(np.mean(errors)) if errors else None,
        "error_max": float(np.max(errors)) if errors else None,
    }
