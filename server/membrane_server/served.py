"""A scene ready to answer: its evaluator (films) and engine (live sessions) built once, its
time grid, its ``describe`` payload encoded once, its revision.

The dispatcher answers requests with these; a reload builds new ones beside those serving.
"""

from __future__ import annotations

import hashlib
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from membrane_client.coordinates import Extent
from membrane_client.frame import Frame, SceneInfo
from membrane_models.live import LiveEngine, LiveError
from membrane_models.problems import MembraneForced, StringForced
from membrane_server.engine_film import EngineFilmEvaluator, films_from_engine
from membrane_server.engines import UnknownEngine
from membrane_server.evaluators import Evaluator, build_evaluator
from membrane_server.live import build_scene_engine, live_description
from membrane_server.reply_cache import ReplyCache
from membrane_server.reply_encoding import EncodedFields, encode_fields
from membrane_server.scene import Scene, SceneError, load_scene
from membrane_server.source import ModelSource, resolve_source
from membrane_server.timeline import Sample, Timeline
from membrane_server.tissue_scene import (
    SI_STEP_UNITS,
    SI_UNITS,
    RestEvaluator,
    TissueSource,
    tissue_parts,
)

__all__ = ["UNITS", "ServedScene"]

logger = logging.getLogger(__name__)

UNITS = {
    "time": "s (simulation time; model time t = step * dt)",
    "lattice": "problem units (nondimensional, the model's spatial domain)",
    "displacement": "problem units (nondimensional)",
    "world": "simulator units: origin + size * lattice coordinate, + scale * displacement",
}


class ServedScene:
    """A scene ready to answer: its evaluator built once, its time grid, its describe payload."""

    def __init__(
        self,
        scene: Scene,
        evaluator: Evaluator,
        source: ModelSource | TissueSource,
        live: LiveEngine[Any] | None = None,
    ) -> None:
        self.scene = scene
        self.evaluator = evaluator
        self.source = source
        self.live = live  # a live scene's engine: sessions step it (membrane_server.live)
        self.timeline = Timeline(
            dt=scene.dt,
            last_step=scene.last_step,
            start_offset=scene.start_offset,
            snapping=scene.snapping,
            policy=scene.policy,
        )
        self.shape = scene.lattice.shape
        description = self._describe()
        # Encoded once: a 65,536-point lattice's describe is a megabyte of coordinates.
        encoded = encode_fields(description)
        # The revision names this content: a reload that changes anything a client relies on
        # (lattice, placement, time grid, model) changes it, and clients see it in every reply.
        self.revision = hashlib.sha256(encoded.data).hexdigest()[:12]
        self._description = {**description, "revision": self.revision}
        self.encoded_description = encoded.plus("revision", self.revision)
        self._replies = ReplyCache()

    @classmethod
    def load(cls, scene: Scene | str | Path, threads: int = 1) -> ServedScene:
        """Load a scene (object, built-in name or path), resolve its model once, build its
        evaluator from that."""
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        if scene.tissue is not None:
            return cls._load_tissue(scene)
        source = resolve_source(scene)
        started = time.perf_counter()
        try:
            engine = None if scene.live is None else build_scene_engine(scene, source.problem)
            evaluator = _film(scene, source, engine, threads)
        except (SceneError, LiveError, UnknownEngine) as exc:  # where the file is not known
            raise scene.error(exc) from None
        logger.info(
            "scene %s: %s evaluator, %d points, model %s, built in %.2f s",
            scene.name, evaluator.kind, evaluator.n_points, source.summary()["name"],
            time.perf_counter() - started,
        )  # fmt: skip
        return cls(scene, evaluator, source, engine)

    @classmethod
    def _load_tissue(cls, scene: Scene) -> ServedScene:
        """A physical scene: its tissue meshed, its FEM engine built (tables from the cache)."""
        started = time.perf_counter()
        tissue, source, evaluator = tissue_parts(scene)
        try:
            engine = build_scene_engine(scene, tissue)
        except (SceneError, LiveError, UnknownEngine) as exc:
            raise scene.error(exc) from None
        logger.info(
            "scene %s: %s tissue, %d points, %d modes, built in %.2f s",
            scene.name, tissue.name, evaluator.n_points, tissue.modes,
            time.perf_counter() - started,
        )  # fmt: skip
        return cls(scene, evaluator, source, engine)

    @property
    def name(self) -> str:
        """The scene's name."""
        return self.scene.name

    def describe(self) -> dict[str, Any]:
        """The ``describe`` reply's fields."""
        return self._description

    def query(self, t: float, dtype: str = "<f4") -> dict[str, Any]:
        """The ``query`` reply's fields for simulation time ``t`` (raises OutOfDomain)."""
        return self._served_frame(self.timeline.resolve(t), t).to_reply_fields(dtype)

    def encoded_query(self, t: float, dtype: str = "<f4") -> EncodedFields:
        """``query``'s fields but ``requested_t``, encoded; those of a time on a step come
        from the reply cache (raises OutOfDomain)."""
        sample = self.timeline.resolve(t)

        def fields() -> EncodedFields:
            frame = self._served_frame(sample, t)
            return encode_fields(frame.to_reply_fields(dtype, requested=False))

        if sample.weight != 0.0:  # between two steps: interpolated, not cached
            return fields()
        return self._replies.get((sample.step, dtype, sample.domain), fields)

    def _served_frame(self, sample: Sample, requested_t: float) -> Frame:
        z = self.frame(sample).reshape(self.shape)
        domain = str(sample.domain)
        return Frame(
            sample.t, sample.step, z, requested_t, domain, self.name, revision=self.revision
        )

    def frame(self, sample: Sample) -> np.ndarray:
        """The (n,) displacement for a resolved sample (interpolated under linear snapping)."""
        frame = self.evaluator.frame(self.timeline.model_time(sample.step))
        if sample.weight == 0.0:
            return frame
        following = self.evaluator.frame(self.timeline.model_time(sample.step + 1))
        mixed: np.ndarray = (1.0 - sample.weight) * frame + sample.weight * following
        return mixed

    def _describe(self) -> dict[str, Any]:
        scene, placement = self.scene, self.scene.placement
        fields: dict[str, Any] = SceneInfo(
            name=scene.name,
            description=scene.description,
            points=self.evaluator.points,
            shape=tuple(self.shape),
            dt=scene.dt,
            duration=scene.duration,
            start_offset=scene.start_offset,
            steps=scene.steps,
            origin=np.asarray(placement.origin, dtype=np.float64),
            size=placement.size,
            scale=placement.scale,
            axis=placement.axis,
            policy=scene.policy,
            snapping=scene.snapping,
            evaluator=self.evaluator.kind,
            evaluator_info={k: v for k, v in self.evaluator.info().items() if k != "kind"},
            model=self.source.summary(),
            units=SI_UNITS if scene.tissue is not None else UNITS,
            live={} if self.live is None else live_description(self.live, self._step_units()),
            # Said only where they say something: a film scene's describe stays protocol v1's.
            declared_extent=None if scene.film else self._extent(),
            film=scene.film,
            triangles=self._triangles(),
        ).to_reply_fields()
        return fields

    def _extent(self) -> Extent:
        lower, upper = zip(*self.source.spatial_bounds, strict=True)
        return Extent.of_bounds(np.array(lower), np.array(upper))

    def _triangles(self) -> np.ndarray | None:
        """A physical 2-D scene's lattice triangles on its tissue (``lattice_surface``)."""
        if not isinstance(self.source, TissueSource):
            return None
        return self.source.lattice_triangles(self.evaluator.points, tuple(self.shape))

    def _step_units(self) -> dict[str, str] | None:
        return None if self.scene.tissue is None else SI_STEP_UNITS


def _film(
    scene: Scene, source: ModelSource, engine: LiveEngine[Any] | None, threads: int
) -> Evaluator:
    """What answers ``query``: the rest shape (no film), the live engine's own film (a live
    scene on a forced problem, so that film and sessions agree), or the scene's evaluator."""
    if not scene.film:
        return RestEvaluator(scene.lattice.coordinates(source.spatial_bounds))
    problem = source.problem
    forced = isinstance(problem, StringForced | MembraneForced)
    if source.manifest is None and forced and films_from_engine(problem, engine):
        assert engine is not None and isinstance(problem, StringForced | MembraneForced)
        return EngineFilmEvaluator(scene, problem, engine)
    return build_evaluator(scene, source, threads=threads)
