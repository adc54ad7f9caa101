"""Small untrained ONNX models that follow the manifest contract
(membrane_models.artifacts.manifest).

Built with the ``onnx`` helper API, so server tests need no training and no torch. Each model is
separable by construction:

    A(x)  = tanh(x W1 + b1) * prod_j x_j (1 - x_j) * amplitude      (n, r)   "space" graph
    B(t)  = t^2 * cos(t w2 + c2)                                      (m, r)   "time" graph
    u     = sum_k A_k(x) B_k(t) + bias                               (n, 1)   "full" graph

The full graph computes the product itself (it does not call the part-graphs), so comparing the
``separable`` evaluator with the ``network`` one compares two different computations.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from membrane_models.artifacts.manifest import GraphFile, Manifest, sha256_of
from membrane_models.problems import make_problem

__all__ = ["TestModel", "build_test_model", "reference_full"]

OPSET = 17
PROBLEM_FOR_DIMS = {1: "string-forced", 2: "membrane-forced"}


@dataclass(frozen=True)
class TestModel:
    """A test model on disk and the weights it was built from (to compute references)."""

    manifest_path: Path
    spatial_dims: int
    rank: int
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    c2: np.ndarray
    amplitude: float
    bias: float

    @property
    def full_path(self) -> Path:
        """The full graph's file."""
        return self.manifest_path.with_suffix(".onnx")


def _const(name: str, value: np.ndarray) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(value, dtype=np.float32), name)


def _space_nodes(x: str, out: str, dims: int, prefix: str) -> list[onnx.NodeProto]:
    """Nodes computing A from the (n, dims) tensor named ``x`` into ``out``."""
    p = prefix
    nodes = [
        helper.make_node("MatMul", [x, "W1"], [f"{p}xw"]),
        helper.make_node("Add", [f"{p}xw", "b1"], [f"{p}pre"]),
        helper.make_node("Tanh", [f"{p}pre"], [f"{p}act"]),
        helper.make_node("Sub", ["one", x], [f"{p}omx"]),
        helper.make_node("Mul", [x, f"{p}omx"], [f"{p}edge"]),  # (n, dims): x_j (1 - x_j)
    ]
    if dims == 1:
        factor = f"{p}edge"
    else:
        nodes += [
            helper.make_node("Slice", [f"{p}edge", "i0", "i1", "ax1"], [f"{p}e0"]),
            helper.make_node("Slice", [f"{p}edge", "i1", "i2", "ax1"], [f"{p}e1"]),
            helper.make_node("Mul", [f"{p}e0", f"{p}e1"], [f"{p}factor"]),
        ]
        factor = f"{p}factor"
    nodes += [
        helper.make_node("Mul", [f"{p}act", factor], [f"{p}shaped"]),
        helper.make_node("Mul", [f"{p}shaped", "amplitude"], [out]),
    ]
    return nodes


def _time_nodes(t: str, out: str, prefix: str) -> list[onnx.NodeProto]:
    """Nodes computing B from the (m, 1) tensor named ``t`` into ``out``."""
    p = prefix
    return [
        helper.make_node("Mul", [t, "w2"], [f"{p}tw"]),
        helper.make_node("Add", [f"{p}tw", "c2"], [f"{p}phase"]),
        helper.make_node("Cos", [f"{p}phase"], [f"{p}cos"]),
        helper.make_node("Mul", [t, t], [f"{p}t2"]),
        helper.make_node("Mul", [f"{p}cos", f"{p}t2"], [out]),
    ]


def _save(
    nodes: list[onnx.NodeProto],
    initializers: list[onnx.TensorProto],
    inputs: tuple[str, int],
    outputs: tuple[str, int | str],
    path: Path,
) -> None:
    in_name, in_width = inputs
    out_name, out_width = outputs
    graph = helper.make_graph(
        nodes,
        path.stem,
        [helper.make_tensor_value_info(in_name, TensorProto.FLOAT, ["n", in_width])],
        [helper.make_tensor_value_info(out_name, TensorProto.FLOAT, ["n", out_width])],
        initializer=initializers,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8  # readable by every onnxruntime >= 1.14
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def build_test_model(
    directory: Path,
    name: str,
    spatial_dims: int = 2,
    rank: int = 8,
    seed: int = 0,
    amplitude: float = 1e-3,
    bias: float = 1e-6,
    separable: bool = True,
) -> TestModel:
    """Write ``name.onnx`` (+ ``name.space.onnx``, ``name.time.onnx``) and ``name.json``.

    Args:
        directory: Where the files go.
        name: Model name (file stem).
        spatial_dims: 1 (a string) or 2 (a membrane); sets the manifest's problem.
        rank: Number of separable terms r.
        seed: Seed of the random weights.
        amplitude: Output scale (real responses are about 5e-4).
        bias: Constant added to the output.
        separable: Also write the space/time part-graphs and list them in the manifest.
    """
    rng = np.random.default_rng(seed)
    w1 = rng.normal(0.0, 2.0, (spatial_dims, rank))
    b1 = rng.normal(0.0, 0.5, (rank,))
    w2 = rng.normal(0.0, 6.0, (1, rank))
    c2 = rng.normal(0.0, 1.0, (rank,))
    weights = [
        _const("W1", w1), _const("b1", b1), _const("w2", w2), _const("c2", c2),
        _const("amplitude", np.array(amplitude)), _const("one", np.array(1.0)),
        _const("bias", np.array([[bias]])),
    ]  # fmt: skip
    slices = [numpy_helper.from_array(np.array([k], dtype=np.int64), f"i{k}") for k in range(3)] + [
        numpy_helper.from_array(np.array([1], dtype=np.int64), "ax1")
    ]
    directory.mkdir(parents=True, exist_ok=True)
    d = spatial_dims

    full_nodes = [
        helper.make_node("Slice", ["xt", "i0", f"i{d}", "ax1"], ["x_part"]),
        helper.make_node("Slice", ["xt", f"i{d}", "i_end", "ax1"], ["t_part"]),
        *_space_nodes("x_part", "A", d, "s_"),
        *_time_nodes("t_part", "B", "t_"),
        helper.make_node("Mul", ["A", "B"], ["AB"]),
        helper.make_node("ReduceSum", ["AB", "ax1"], ["sum"], keepdims=1),
        helper.make_node("Add", ["sum", "bias"], ["u"]),
    ]  # fmt: skip
    end = [numpy_helper.from_array(np.array([d + 1], dtype=np.int64), "i_end")]
    graphs = {"full": GraphFile(f"{name}.onnx", "", "xt", "u")}
    _save(full_nodes, weights + slices + end, ("xt", d + 1), ("u", 1), directory / f"{name}.onnx")
    if separable:
        space_file, time_file = directory / f"{name}.space.onnx", directory / f"{name}.time.onnx"
        _save(_space_nodes("x", "A", d, "s_"), weights + slices, ("x", d), ("A", rank), space_file)
        _save(_time_nodes("t", "B", "t_"), weights, ("t", 1), ("B", rank), time_file)
        graphs["space"] = GraphFile(space_file.name, "", "x", "A")
        graphs["time"] = GraphFile(time_file.name, "", "t", "B")
    graphs = {
        role: GraphFile(g.file, sha256_of(directory / g.file), g.input, g.output)
        for role, g in graphs.items()
    }
    problem = make_problem(PROBLEM_FOR_DIMS[spatial_dims])
    domain = {axis: [0.0, 1.0] for axis in ("x", "y")[:spatial_dims]}
    domain["t"] = [0.0, float(problem.t_end)]
    manifest = Manifest(
        name=name,
        problem=problem.name,
        parameters=problem.parameters(),
        domain=domain,
        architecture={"name": "untrained test graph", "rank": rank, "seed": seed},
        graphs=graphs,
        rank=rank if separable else 0,
        bias=bias,
        training={"note": "untrained: random weights for tests"},
        error={},
    )
    manifest_path = directory / f"{name}.json"
    manifest.write(manifest_path)
    return TestModel(manifest_path, spatial_dims, rank, w1, b1, w2, c2, amplitude, bias)


def reference_full(model: TestModel, points: np.ndarray, t: float) -> np.ndarray:
    """The model's output computed with numpy in float64 (for sanity checks of the graphs)."""
    x = np.asarray(points, dtype=np.float64)
    space = np.tanh(x @ model.w1 + model.b1) * np.prod(x * (1 - x), axis=1, keepdims=True)
    space = space * model.amplitude
    time_factor = t**2 * np.cos(t * model.w2[0] + model.c2)
    result: np.ndarray = space @ time_factor + model.bias
    return result
