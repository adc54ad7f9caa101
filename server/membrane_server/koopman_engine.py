"""The ``koopman`` live engine: a learned Koopman model of the nonlinear string, on onnxruntime.

A session's initial displacement and velocity (on the scene's lattice: the model's 128 interior
points and the two clamped ends) are encoded once into the latent state z; each step runs the
step graph, z <- K(z) z (rotations of modulus 1: nothing grows, nothing decays); a frame is the
decoder's u, the ends 0. The graphs come from the zoo's ``koopman/`` folder, their sha256
checked at load; torch is never imported (the server's import contract).

The model knows only what it was trained on: the Kirchhoff-Carrier string of its manifest, its
dt, its lattice, initial states up to the training set's largest nonlinearity k S* / c^2. The
engine refuses the rest (a scene of another problem, dt or lattice at load; a larger shape at
open) instead of extrapolating. It takes no loads or probes: its latent dynamics have no input.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.artifacts.koopman_manifest import (
    KoopmanManifest,
    find_koopman_model,
    list_koopman_models,
)
from membrane_models.exact.kirchhoff_carrier import KirchhoffString
from membrane_models.live import (
    InvalidEngineSettings,
    InvalidShape,
    InvalidState,
    Load,
    Probe,
    Start,
    StepResult,
)
from membrane_models.live.projection import checked_shape
from membrane_models.problems import Problem
from membrane_server.runtime import GraphRunner

__all__ = ["KOOPMAN_OPTIONS", "KoopmanEngine", "KoopmanState", "build_koopman_engine"]

FloatArray = NDArray[np.float64]

KOOPMAN_OPTIONS = {"model": 'the zoo\'s Koopman model (default "koopman-string")'}
_DEFAULT_MODEL = "koopman-string"
_ids = itertools.count(1)


@dataclass(frozen=True)
class KoopmanState:
    """A latent state (read-only float32) and the engine it belongs to."""

    z: NDArray[np.float32]
    engine: int


class KoopmanEngine:
    """The Koopman model as a ``LiveEngine`` (see the module docstring)."""

    def __init__(
        self, manifest: KoopmanManifest, problem: Problem, lattice: int, dt: float
    ) -> None:
        self.manifest = manifest
        self._check(problem, lattice, dt)
        self._id = next(_ids)
        self._lattice = (lattice,)
        self._dt = float(dt)
        self._encoder = self._graph("encoder")
        self._step = self._graph("step")
        self._decoder = self._graph("decoder")
        self._string = KirchhoffString(manifest.parameters["c"], manifest.parameters["stretch"])
        points = manifest.points
        x = np.arange(1, points + 1) / (points + 1)
        self._project = 2.0 / (points + 1) * np.sin(np.pi * np.outer(x, np.arange(1, points + 1)))
        data = manifest.training.get("data", {})
        bounds = data.get("nonlinearity") or [1e-3, 1.0]
        self.max_nonlinearity = float(bounds[1])

    def _graph(self, role: str) -> GraphRunner:
        spec = self.manifest.graphs[role]
        return GraphRunner(self.manifest.verify(role), spec.input, spec.output)

    def _check(self, problem: Problem, lattice: int, dt: float) -> None:
        m = self.manifest
        if problem.name != m.problem:
            raise InvalidEngineSettings(
                f"the koopman engine {m.name!r} steps {m.problem}, not {problem.name}"
            )
        params = problem.parameters()
        for name, value in m.parameters.items():
            if not math.isclose(float(params.get(name, math.nan)), value, rel_tol=1e-12):
                raise InvalidEngineSettings(
                    f"the koopman engine {m.name!r} was trained with {name} = {value:g}, the "
                    f"scene's problem has {params.get(name)}"
                )
        if lattice != m.points + 2:
            raise InvalidEngineSettings(
                f"the koopman engine {m.name!r} needs a lattice of nx = {m.points + 2} (its "
                f"{m.points} points and the two clamped ends), got {lattice}"
            )
        if not math.isclose(dt, m.dt, rel_tol=1e-9):
            raise InvalidEngineSettings(f"the koopman engine {m.name!r} steps dt = {m.dt:g} only")

    # ------------------------------------------------------------ LiveEngine

    @property
    def spatial_dims(self) -> int:
        return 1

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        return self._lattice

    @property
    def dt(self) -> float:
        return self._dt

    @property
    def inputs(self) -> frozenset[str]:
        return frozenset({"initial"})

    @property
    def state_bytes(self) -> int:
        return 4 * self.manifest.latent + 64

    def describe(self) -> dict[str, object]:
        m = self.manifest
        errors = m.errors
        rows = [
            [
                r["family"],
                r["band"],
                r["trajectories"],
                *[r["errors"][str(s)] for s in errors["steps"]],
            ]
            for r in errors.get("rows", [])
        ]
        return {
            "engine": "koopman",
            "inputs": sorted(self.inputs),
            "model": m.name,
            "problem": m.problem,
            "lattice": list(self._lattice),
            "dt": self._dt,
            "latent": m.latent,
            "eigenvalue_modulus_max": m.spectrum.get("modulus_max"),
            "max_nonlinearity": self.max_nonlinearity,
            "error_steps": list(errors.get("steps", [])),
            "error_columns": ["family", "band", "trajectories", "error at each of error_steps"],
            "error_table": rows,
            "error_metric": errors.get("metric", ""),
            "state_bytes": self.state_bytes,
        }

    def start(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Start[KoopmanState]:
        n = self._lattice[0]
        u = (
            np.zeros(n)
            if displacement is None
            else checked_shape(displacement, self._lattice, "displacement")
        )
        v = np.zeros(n) if velocity is None else checked_shape(velocity, self._lattice, "velocity")
        state = np.concatenate([u[1:-1], v[1:-1]])[None]
        self._check_nonlinearity(state)
        z = self._encoder.run(state)[0]
        z.setflags(write=False)
        decoded = self._decoder.run(z[None])[0].astype(np.float64)
        points = self.manifest.points
        return Start(
            KoopmanState(z, self._id),
            _residual(u, decoded[:points]),
            _residual(v, decoded[points:]),
        )

    def _check_nonlinearity(self, state: FloatArray) -> None:
        points = self.manifest.points
        q, p = state[:, :points] @ self._project, state[:, points:] @ self._project
        eps = float(self._string.nonlinearity(q, p)[0])
        if eps > self.max_nonlinearity * (1.0 + 1e-9):
            raise InvalidShape(
                f"the initial state's nonlinearity k S*/c^2 is {eps:.3g}, beyond the "
                f"{self.max_nonlinearity:g} the model {self.manifest.name!r} was trained up to"
            )

    def step(
        self,
        state: KoopmanState,
        loads: Sequence[Load] = (),
        probes: Sequence[Probe] = (),
        *,
        frame: bool = True,
    ) -> StepResult[KoopmanState]:
        self._own(state)
        if loads or probes:
            raise InvalidState("the koopman engine takes no loads or probes")
        z = self._step.run(state.z[None])[0]
        z.setflags(write=False)
        new = KoopmanState(z, self._id)
        return StepResult(new, self.frame(new) if frame else None, (), None)

    def frame(self, state: KoopmanState) -> FloatArray:
        self._own(state)
        decoded = self._decoder.run(state.z[None])[0]
        out = np.zeros(self._lattice[0])
        out[1:-1] = decoded[: self.manifest.points]
        return out

    def energy(self, state: KoopmanState) -> float:
        """The decoded state's energy (the string's, from its sine series)."""
        self._own(state)
        decoded = self._decoder.run(state.z[None])[0].astype(np.float64)
        points = self.manifest.points
        q, p = decoded[:points] @ self._project, decoded[points:] @ self._project
        return float(self._string.energy(q, p))

    def _own(self, state: object) -> None:
        if not isinstance(state, KoopmanState) or state.engine != self._id:
            raise InvalidState("a state from another engine")


def _residual(given: FloatArray, decoded: FloatArray) -> float:
    norm = float(np.linalg.norm(given))
    if norm == 0.0:
        return 0.0
    full = np.zeros_like(given)
    full[1:-1] = decoded
    return float(np.linalg.norm(given - full)) / norm


def build_koopman_engine(
    problem: Problem, lattice: tuple[int, ...], dt: float, options: Mapping[str, object]
) -> KoopmanEngine:
    """The ``koopman`` engine kind: the zoo model ``options["model"]`` on the scene's lattice.

    Raises:
        InvalidEngineSettings: an unknown option or model, or a scene the model was not
            trained for (problem, parameters, lattice, dt).
    """
    unknown = sorted(set(options) - set(KOOPMAN_OPTIONS))
    if unknown:
        raise InvalidEngineSettings(f"unknown [live] option {unknown[0]!r:.40}; known: model")
    name = options.get("model", _DEFAULT_MODEL)
    if not isinstance(name, str):
        raise InvalidEngineSettings("[live] model must be a string")
    manifest = find_koopman_model(name) if name in list_koopman_models() else None
    if manifest is None:
        known = ", ".join(list_koopman_models()) or "none shipped"
        raise InvalidEngineSettings(f"[live] model {name!r:.64}: no such Koopman model ({known})")
    if len(lattice) != 1:
        raise InvalidEngineSettings("the koopman engine steps a string: a 1-D lattice")
    return KoopmanEngine(manifest, problem, lattice[0], dt)
