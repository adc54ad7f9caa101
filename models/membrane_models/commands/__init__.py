"""The `membrane` commands of this package: `exact`, `train`, `export`, `evaluate`, `data`, and
the plotting they share. Each module registers its commands (entry points in pyproject.toml)."""
