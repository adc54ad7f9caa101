"""onnxruntime session options for the server: default options vs the latency server's own.

Builds a seed-size tanh MLP ([3] + [100] * 3 + [1], random weights) with the onnx helper API,
then times ``InferenceSession.run`` on a 20 x 20 lattice (400 points) with onnxruntime's default
options and with ``membrane_server.runtime.session_options()`` (one intra-op thread, no spinning),
alternating the two in the same run. Prints p50/p99 per configuration and their ratio.

    python benchmarks/ort_session_options.py [--calls 2000]
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from membrane_server.runtime import session_options


def build_mlp(path: Path, widths: list[int], seed: int = 0) -> None:
    """A tanh MLP with the given layer widths (input first), saved as ONNX."""
    rng = np.random.default_rng(seed)
    nodes, inits, current = [], [], "xt"
    for layer, (fan_in, fan_out) in enumerate(itertools.pairwise(widths)):
        weight = rng.normal(0.0, 1.0 / np.sqrt(fan_in), (fan_in, fan_out)).astype(np.float32)
        inits += [numpy_helper.from_array(weight, f"W{layer}"),
                  numpy_helper.from_array(np.zeros(fan_out, np.float32), f"b{layer}")]  # fmt: skip
        nodes += [helper.make_node("MatMul", [current, f"W{layer}"], [f"m{layer}"]),
                  helper.make_node("Add", [f"m{layer}", f"b{layer}"], [f"a{layer}"])]  # fmt: skip
        current = f"a{layer}"
        if layer < len(widths) - 2:
            nodes.append(helper.make_node("Tanh", [current], [f"h{layer}"]))
            current = f"h{layer}"
    nodes.append(helper.make_node("Identity", [current], ["u"]))
    graph = helper.make_graph(
        nodes, "mlp",
        [helper.make_tensor_value_info("xt", TensorProto.FLOAT, ["n", widths[0]])],
        [helper.make_tensor_value_info("u", TensorProto.FLOAT, ["n", widths[-1]])],
        initializer=inits,
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(path))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "mlp.onnx"
        build_mlp(path, [3, 100, 100, 100, 1])
        sessions = {
            "default options": ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]),
            "server options": ort.InferenceSession(
                str(path), sess_options=session_options(), providers=["CPUExecutionProvider"]
            ),
        }
        grid = np.stack(np.meshgrid(np.linspace(0, 1, 20), np.linspace(0, 1, 20)), -1)
        xt = np.hstack([grid.reshape(-1, 2), np.full((400, 1), 0.5)]).astype(np.float32)
        timings: dict[str, list[float]] = {name: [] for name in sessions}
        for _ in range(args.calls):  # alternate, so both see the same machine state
            for name, session in sessions.items():
                xt[:, 2] = np.float32(np.random.random())
                started = time.perf_counter()
                session.run(["u"], {"xt": xt})
                timings[name].append(time.perf_counter() - started)
    base = np.percentile(np.array(timings["default options"]) * 1e6, [50, 99])
    for name, values in timings.items():
        p50, p99 = np.percentile(np.array(values) * 1e6, [50, 99])
        print(f"{name:>16}: p50 {p50:7.0f} us  p99 {p99:7.0f} us  "
              f"(ratio to default: p50 {p50 / base[0]:.2f}, p99 {p99 / base[1]:.2f})")  # fmt: skip


if __name__ == "__main__":
    main()
