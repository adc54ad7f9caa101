"""The Koopman model's manifest: three graphs (encoder, step, decoder) and their error table.

A Koopman model is not a function of (x, t) like the PINNs (``manifest.Manifest``): it takes
the initial state at run time and steps it. Its graphs take and return float32:

``encoder``  ``state`` (n, 2 P): (u, u_t) on the P interior points x_i = i / (P + 1) -> ``z``
             (n, L), the latent state;
``step``     ``z`` (n, L) -> ``z_next`` (n, L): one step of dt, z_next = K(z) z;
``decoder``  ``z`` (n, L) -> ``state`` (n, 2 P): (u, u_t) again.

The manifest lives in the zoo's ``koopman/`` folder, apart from the PINNs' (whose loaders,
served evaluators and trade-off harness read every ``zoo/*.json`` as a function of (x, t)).
Every graph is listed with its sha256, checked before a graph is loaded.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from membrane_models.artifacts.manifest import GraphFile, ManifestError, sha256_of
from membrane_models.artifacts.zoo_index import ZOO_DIR

__all__ = [
    "KOOPMAN_DIR",
    "KOOPMAN_FORMAT",
    "KOOPMAN_ROLES",
    "KoopmanManifest",
    "find_koopman_model",
    "list_koopman_models",
]

KOOPMAN_FORMAT = 1
KOOPMAN_ROLES = ("encoder", "step", "decoder")
KOOPMAN_DIR = ZOO_DIR / "koopman"


@dataclass(frozen=True)
class KoopmanManifest:
    """What a Koopman model is, how it was made, and how wrong it is.

    Attributes:
        name: The model's name (the manifest's stem).
        problem: The problem it steps (``string-kirchhoff``).
        parameters: That problem's parameters (c, stretch).
        points: Interior points P of a state; x_i = i / (P + 1).
        dt: The step.
        latent: The latent state's size L.
        architecture: The network's configuration.
        graphs: Role -> graph file.
        spectrum: Eigenvalue moduli and the step's frequencies, as measured.
        training: Iterations, wall time, seed, the `membrane train` command.
        errors: The error table (``koopman_evaluate.error_table``) on the test split.
        parity: onnxruntime against torch, per graph (relative L2).
        path: Where it was read from (not serialised).
    """

    name: str
    problem: str
    parameters: dict[str, float]
    points: int
    dt: float
    latent: int
    architecture: dict[str, Any]
    graphs: dict[str, GraphFile]
    spectrum: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    errors: dict[str, Any] = field(default_factory=dict)
    parity: dict[str, float] = field(default_factory=dict)
    kind: str = "koopman"
    format: int = KOOPMAN_FORMAT
    path: Path | None = field(default=None, compare=False)

    def graph_path(self, role: str) -> Path:
        """Absolute path of the graph with this role (a file beside the manifest)."""
        if role not in self.graphs:
            raise ManifestError(f"model {self.name!r} has no {role!r} graph")
        name = self.graphs[role].file
        if Path(name).name != name or name in ("", ".", ".."):
            raise ManifestError(
                f"model {self.name!r}: graph file {name[:64]!r} must be a bare name"
            )
        base = self.path.parent if self.path is not None else Path.cwd()
        return base / name

    def verify(self, role: str) -> Path:
        """Check one graph against its sha256; returns its path."""
        path = self.graph_path(role)
        if not path.is_file():
            raise ManifestError(f"model {self.name!r}: graph file {path} is missing")
        if sha256_of(path) != self.graphs[role].sha256:
            raise ManifestError(f"model {self.name!r}: {path.name} does not match its sha256")
        return path

    def with_errors(self, errors: dict[str, Any]) -> KoopmanManifest:
        return replace(self, errors=errors)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data.pop("path")
        return data

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def read(cls, path: Path) -> KoopmanManifest:
        """Read and check a manifest file."""
        try:
            data = json.loads(path.read_text())
            if data.get("kind") != "koopman" or int(data.get("format", 0)) != KOOPMAN_FORMAT:
                raise ManifestError(f"{path} is not a Koopman manifest of format {KOOPMAN_FORMAT}")
            graphs = {role: GraphFile(**g) for role, g in data.pop("graphs").items()}
            manifest = cls(**{**data, "graphs": graphs, "path": path.resolve()})
        except (OSError, json.JSONDecodeError, TypeError, KeyError) as exc:
            raise ManifestError(f"cannot read Koopman manifest {path}: {exc}") from None
        if set(manifest.graphs) != set(KOOPMAN_ROLES):
            raise ManifestError(f"{path}: graphs must be {', '.join(KOOPMAN_ROLES)}")
        if manifest.points < 1 or manifest.latent < 1 or not math.isfinite(manifest.dt):
            raise ManifestError(f"{path}: points, latent and dt must be positive numbers")
        return manifest

    def table_text(self) -> str:
        """The error table for people: one line per family and band, one column per horizon."""
        return format_table(self.errors)


def format_table(errors: dict[str, Any]) -> str:
    """``errors`` (``koopman_evaluate.error_table``) as an aligned text table."""
    if not errors:
        return "(no error table)"
    steps = [str(s) for s in errors["steps"]]
    head = f"{'family':<13} {'band':<7} {'n':>3} " + " ".join(f"{s + ' steps':>11}" for s in steps)
    lines = [head]
    for row in errors["rows"]:
        cells = " ".join(f"{row['errors'][s]:>11.3e}" for s in steps)
        lines.append(f"{row['family']:<13} {row['band']:<7} {row['trajectories']:>3} {cells}")
    lines.append(f"({errors['metric']})")
    return "\n".join(lines)


def list_koopman_models() -> list[str]:
    """Names of the shipped Koopman models."""
    return sorted(p.stem for p in KOOPMAN_DIR.glob("*.json"))


def find_koopman_model(name_or_path: str | Path) -> KoopmanManifest | None:
    """The Koopman manifest a name or .json path names, or None when it names none."""
    text = str(name_or_path)
    if text in list_koopman_models():
        return KoopmanManifest.read(KOOPMAN_DIR / f"{text}.json")
    path = Path(text)
    if path.suffix == ".json" and path.is_file():
        try:
            kind = json.loads(path.read_text()).get("kind")
        except (OSError, json.JSONDecodeError, AttributeError):
            return None
        if kind == "koopman":
            return KoopmanManifest.read(path)
    return None
