"""Datasets made by the project's own solvers, for data-driven networks (``koopman``: the
Kirchhoff-Carrier string from runtime initial shapes); never the test set."""
