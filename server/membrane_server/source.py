"""What a scene's ``model`` names: a trained model from the zoo (or a path), or a bare problem."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from membrane_models.artifacts.manifest import Manifest
from membrane_models.artifacts.zoo_index import list_models, resolve_model
from membrane_models.problems import PROBLEMS, Problem, make_problem
from membrane_server.scene import Scene, SceneError, problem_overrides

__all__ = ["ModelSource", "resolve_source"]


@dataclass(frozen=True)
class ModelSource:
    """What a scene's ``model`` names: a trained model (manifest) or a bare problem.

    Attributes:
        problem: The problem, with the parameters the model was trained on.
        manifest: The trained model's manifest, or None for a bare problem (exact evaluator).
    """

    problem: Problem
    manifest: Manifest | None = None

    @property
    def spatial_bounds(self) -> list[tuple[float, float]]:
        """(low, high) of every space axis."""
        if self.manifest is None:
            return [(0.0, 1.0)] * self.problem.spatial_dims
        return [
            (bounds[0], bounds[1]) for axis, bounds in self.manifest.domain.items() if axis != "t"
        ]

    @property
    def time_bounds(self) -> tuple[float, float]:
        """(low, high) of the time domain the model is valid on."""
        if self.manifest is None:
            return (0.0, self.problem.t_end)
        low, high = self.manifest.domain["t"]
        return (low, high)

    def summary(self) -> dict[str, Any]:
        """What ``describe`` reports about the model."""
        summary: dict[str, Any] = {
            "problem": self.problem.name,
            "parameters": self.problem.parameters(),
            "domain": {
                **{axis: list(b) for axis, b in zip(("x", "y"), self.spatial_bounds, strict=False)},
                "t": list(self.time_bounds),
            },
        }
        if self.manifest is None:
            summary.update(name=self.problem.name, architecture="exact modal series", error={})
            return summary
        summary.update(
            name=self.manifest.name,
            architecture=self.manifest.architecture,
            error=self.manifest.error,
            rank=self.manifest.rank,
            sha256={role: graph.sha256 for role, graph in self.manifest.graphs.items()},
        )
        return summary


def resolve_source(scene: Scene) -> ModelSource:
    """The model (or problem) a scene names.

    With the exact evaluator a problem name (``membrane-forced``...) means the problem; otherwise
    a name is a zoo model's, and a .json/.onnx path names a model file. Graph hashes are checked
    later, at load.

    Raises:
        SceneError: Unknown model, a problem name with an evaluator that needs a network, or a
            lattice that does not fit the model's space (each naming the scene's file).
    """
    source = _resolve(scene)
    try:  # the lattice against the model's space, here where the scene file can be named
        scene.lattice.coordinates(source.spatial_bounds)
    except SceneError as exc:
        raise scene.error(exc) from None
    return source


def _resolve(scene: Scene) -> ModelSource:
    """The problem, or the trained model's manifest and problem (resolve_source's first part)."""
    path = scene.model_path()
    if path is None and scene.model in PROBLEMS:
        if scene.evaluator == "exact":  # a problem name means the problem here
            overrides = problem_overrides(scene.parameters)  # checked when the scene was read
            return ModelSource(problem=make_problem(scene.model, overrides))
        if scene.model not in list_models():
            raise SceneError(
                f"{scene.where}: model: {scene.model!r} is a problem with no trained model "
                f"in the zoo; evaluator {scene.evaluator!r} needs a zoo model or a .json/.onnx "
                "path (or use evaluator 'exact')"
            )
    try:
        manifest = resolve_model(path if path is not None else scene.model)
        overrides = {key: str(value) for key, value in manifest.parameters.items()}
        problem = make_problem(manifest.problem, overrides)
    except ValueError as exc:  # ManifestError and InvalidProblem are ValueErrors
        raise SceneError(f"{scene.where}: model: {exc}") from None
    return ModelSource(problem=problem, manifest=manifest)
