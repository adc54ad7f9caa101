"""onnxruntime sessions set up for a latency server.

A latency server answers one small request at a time: one intra-op thread and no spinning
thread pools (a spinning pool steals the core that ZeroMQ and msgpack need; anchors.md).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from membrane_models.artifacts.manifest import Manifest
from membrane_server.scene import SceneError

__all__ = ["OPTIMIZATION_LEVELS", "GraphRunner", "load_graph", "session_options"]

logger = logging.getLogger(__name__)

# onnxruntime's graph optimisation levels by name; the server's own is "all".
_LEVELS = {
    "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
    "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
    "disabled": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
}
OPTIMIZATION_LEVELS = tuple(_LEVELS)


def session_options(threads: int = 1, optimization: str = "all") -> ort.SessionOptions:
    """Session options for answering one query at a time with low, steady latency.

    Args:
        threads: Intra-op threads.
        optimization: Graph optimisation level, one of OPTIMIZATION_LEVELS.

    Raises:
        ValueError: An unknown optimisation level.
    """
    if optimization not in _LEVELS:
        known = ", ".join(OPTIMIZATION_LEVELS)
        raise ValueError(f"graph optimisation level {optimization!r}: expected one of {known}")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = _LEVELS[optimization]
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    options.log_severity_level = 3  # warnings from ORT's own graph passes are noise here
    return options


class GraphRunner:
    """One ONNX graph with one float32 input and one float32 output, on the CPU.

    Args:
        path: The .onnx file (already checked against its manifest by the caller).
        input_name: Expected input name (checked), or None to take the graph's only input.
        output_name: Expected output name (checked), or None to take the graph's only output.
        threads: onnxruntime intra-op threads.
        optimization: onnxruntime graph optimisation level (one of OPTIMIZATION_LEVELS).
    """

    def __init__(
        self,
        path: Path,
        input_name: str | None = None,
        output_name: str | None = None,
        threads: int = 1,
        optimization: str = "all",
    ) -> None:
        self.path = path
        options = session_options(threads, optimization)
        try:
            self._session = ort.InferenceSession(
                str(path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own untyped errors for bad files
            message = f"model graph {path.name}: onnxruntime cannot load it: {exc}"
            raise SceneError(message) from None
        self.input_name = _only_name(path, "input", self._session.get_inputs(), input_name)
        self.output_name = _only_name(path, "output", self._session.get_outputs(), output_name)

    def run(self, values: np.ndarray) -> np.ndarray:
        """Run the graph on a float32 array; returns its float32 output."""
        feed = {self.input_name: np.ascontiguousarray(values, dtype=np.float32)}
        outputs = self._session.run([self.output_name], feed)
        return np.asarray(outputs[0])


def _only_name(path: Path, what: str, nodes: list[Any], expected: str | None) -> str:
    names = [node.name for node in nodes]
    if expected is not None:
        if expected not in names:
            raise SceneError(f"model graph {path.name}: no {what} named {expected!r} ({names})")
        return expected
    if len(names) != 1:
        raise SceneError(f"model graph {path.name}: expected one {what}, found {names}")
    return str(names[0])


def load_graph(
    manifest: Manifest, role: str, threads: int = 1, optimization: str = "all"
) -> GraphRunner:
    """Verify one graph of a model against its manifest's sha256, then load it (with
    ``threads`` intra-op threads at graph optimisation level ``optimization``)."""
    path = manifest.verify(role)
    spec = manifest.graphs[role]
    runner = GraphRunner(path, spec.input, spec.output, threads, optimization)
    logger.info("loaded %s graph of model %s (%s)", role, manifest.name, path.name)
    return runner
