"""Everything that needs torch (the `train` extra): the architectures, the PINN networks and
their input/output transforms, training and ONNX export. The server never imports this package
(an import-linter contract)."""
