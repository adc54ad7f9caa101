"""Finding models: the shipped zoo (package data) or a manifest/graph path given by the user."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from membrane_models.artifacts.manifest import Manifest, ManifestError

__all__ = ["ZOO_DIR", "list_models", "resolve_model"]

ZOO_DIR = Path(str(resources.files("membrane_models") / "zoo"))


def list_models() -> list[str]:
    """Names of the shipped models (manifest stems in the zoo), sorted."""
    return sorted(p.stem for p in ZOO_DIR.glob("*.json"))


def resolve_model(name_or_path: str | Path) -> Manifest:
    """The manifest of a zoo model by name, or of a model given as a .json or .onnx path.

    For ``MODEL.onnx`` (or a part-graph ``MODEL.space.onnx``) the manifest is ``MODEL.json``
    beside it. Graph hashes are not checked here: ``Manifest.verify`` does that before loading.
    """
    text = str(name_or_path)
    path = Path(text)
    if path.suffix not in (".json", ".onnx"):
        if path.name != text or text in ("", ".", ".."):  # a zoo name, never a way out of it
            raise ManifestError(
                f"unknown model {text[:64]!r}: a zoo model's name has no '/' or '..' (a model "
                "file is named by its .json or .onnx path)"
            )
        candidate = ZOO_DIR / f"{text}.json"
        if not candidate.is_file():
            known = ", ".join(list_models()) or "none shipped"
            raise ManifestError(f"unknown model {text!r}; zoo models: {known}")
        return Manifest.read(candidate)
    if path.suffix == ".onnx":
        stem = path.name.removesuffix(".onnx").removesuffix(".space").removesuffix(".time")
        path = path.with_name(f"{stem}.json")
    if not path.is_file():
        raise ManifestError(f"no manifest at {path}")
    return Manifest.read(path)
