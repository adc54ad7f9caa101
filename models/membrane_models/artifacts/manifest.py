"""The model manifest: the JSON file beside every exported model, and the server's contract.

A model is one or more ONNX graphs plus ``<name>.json``. The graphs take and return float32:

``full``   input ``xt`` of shape (n, d + 1), columns (x[, y], t) -> output ``u`` of shape (n, 1),
           the displacement itself (all input/output scaling inside the graph).
``space``  (separable models only) input ``x`` of shape (n, d) -> output ``A`` of shape (n, r),
           boundary factor and output scaling included.
``time``   (separable models only) input ``t`` of shape (m, 1) -> output ``B`` of shape (m, r).

For a separable model u(x_i, t_j) = sum_k A[i, k] B[j, k] + ``bias``: the full graph equals
A @ B^T + bias. Every graph file is listed with its sha256, which loaders check before use.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from membrane_errors import UserError

__all__ = [
    "MANIFEST_FORMAT",
    "GraphFile",
    "Manifest",
    "ManifestError",
    "sha256_of",
]

MANIFEST_FORMAT = 1
GRAPH_ROLES = ("full", "space", "time")


class ManifestError(UserError):
    """A manifest that cannot be read, or a graph file that does not match it."""


def sha256_of(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class GraphFile:
    """One ONNX graph of a model: its file (relative to the manifest) and its sha256."""

    file: str
    sha256: str
    input: str
    output: str


@dataclass(frozen=True)
class Manifest:
    """What a model is, how it was made, and how wrong it is.

    Attributes:
        name: Model name (the zoo's key), also the stem of the manifest file.
        problem: Registry name of the problem (``membrane_models.problems.PROBLEMS``).
        parameters: The problem's parameters as trained.
        domain: Axis name -> [low, high], space axes first, then "t".
        architecture: Name and hyperparameters of the network.
        graphs: Role ("full", "space", "time") -> graph file.
        rank: Number of separable terms r (0 for a non-separable model).
        bias: Constant added to A @ B^T (separable models).
        training: Iterations, wall time in seconds, seed, the exact `membrane train` command, ...
        error: Measured error against the exact solution: relative_l2, max_abs, grid.
        path: Where the manifest was read from (not serialised).
    """

    name: str
    problem: str
    parameters: dict[str, float]
    domain: dict[str, list[float]]
    architecture: dict[str, Any]
    graphs: dict[str, GraphFile]
    rank: int = 0
    bias: float = 0.0
    training: dict[str, Any] = field(default_factory=dict)
    error: dict[str, Any] = field(default_factory=dict)
    format: int = MANIFEST_FORMAT
    path: Path | None = field(default=None, compare=False)

    @property
    def separable(self) -> bool:
        """True when the model ships ``space`` and ``time`` part-graphs."""
        return "space" in self.graphs and "time" in self.graphs

    @property
    def spatial_dims(self) -> int:
        """Number of space axes (1 for a string, 2 for a membrane)."""
        return len(self.domain) - 1

    def graph_path(self, role: str) -> Path:
        """Absolute path of the graph with this role."""
        if role not in self.graphs:
            raise ManifestError(f"model {self.name!r} has no {role!r} graph")
        base = self.path.parent if self.path is not None else Path.cwd()
        name = self.graphs[role].file
        # A graph lies beside its manifest: a path out of that folder would let a manifest
        # (which may come from elsewhere than the model's author) load any file.
        if Path(name).name != name or name in ("", ".", ".."):
            raise ManifestError(
                f"model {self.name!r}: graph file {name[:64]!r} must be a file name in the "
                "manifest's own folder (no directories, no '..')"
            )
        return base / name

    def verify(self, role: str) -> Path:
        """Check one graph file against its sha256; returns its path."""
        path = self.graph_path(role)
        if not path.is_file():
            raise ManifestError(f"model {self.name!r}: graph file {path} is missing")
        actual = sha256_of(path)
        if actual != self.graphs[role].sha256:
            raise ManifestError(
                f"model {self.name!r}: {path.name} sha256 {actual[:12]}... does not match the "
                f"manifest's {self.graphs[role].sha256[:12]}... (file altered or corrupted)"
            )
        return path

    def to_dict(self) -> dict[str, Any]:
        """Plain data for JSON (``path`` left out)."""
        data = asdict(self)
        data.pop("path")
        return data

    def write(self, path: Path) -> None:
        """Write the manifest as indented JSON."""
        path.write_text(json.dumps(self.to_dict(), indent=2, sort_keys=False) + "\n")

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: Path | None = None) -> Manifest:
        """Build from parsed JSON, checking the fields the server relies on."""
        try:
            fmt = int(data.get("format", MANIFEST_FORMAT))
            if fmt != MANIFEST_FORMAT:
                raise ManifestError(
                    f"manifest format {fmt} unsupported (expected {MANIFEST_FORMAT})"
                )
            graphs = {role: GraphFile(**g) for role, g in data["graphs"].items()}
            manifest = cls(
                name=str(data["name"]),
                problem=str(data["problem"]),
                parameters={k: float(v) for k, v in data["parameters"].items()},
                domain={k: [float(v[0]), float(v[1])] for k, v in data["domain"].items()},
                architecture=dict(data["architecture"]),
                graphs=graphs,
                rank=int(data.get("rank", 0)),
                bias=float(data.get("bias", 0.0)),
                training=dict(data.get("training", {})),
                error=dict(data.get("error", {})),
                format=fmt,
                path=path,
            )
        except (KeyError, TypeError, IndexError) as exc:
            where = f" {path}" if path else ""
            raise ManifestError(f"malformed manifest{where}: {exc!r}") from None
        manifest._check()
        return manifest

    @classmethod
    def read(cls, path: Path) -> Manifest:
        """Read a manifest file."""
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ManifestError(f"cannot read manifest {path}: {exc}") from None
        return cls.from_dict(data, path=path.resolve())

    def _check(self) -> None:
        unknown = set(self.graphs) - set(GRAPH_ROLES)
        if unknown:
            raise ManifestError(f"manifest {self.name!r}: unknown graph roles {sorted(unknown)}")
        if "full" not in self.graphs:
            raise ManifestError(f"manifest {self.name!r}: no 'full' graph")
        if ("space" in self.graphs) != ("time" in self.graphs):
            raise ManifestError(f"manifest {self.name!r}: 'space' and 'time' come together")
        if self.separable and self.rank <= 0:
            raise ManifestError(f"manifest {self.name!r}: a separable model needs rank > 0")
        if "t" not in self.domain or len(self.domain) not in (2, 3):
            raise ManifestError(f"manifest {self.name!r}: domain must be (x[, y], t)")
        if not math.isfinite(self.bias):
            raise ManifestError(f"manifest {self.name!r}: bias must be finite")
