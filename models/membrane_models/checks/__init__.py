"""Independent cross-checks of the exact solutions: finite differences written apart from them
(``linear_fd`` for the linear problems, ``kirchhoff_fd`` for the Kirchhoff-Carrier string)."""
