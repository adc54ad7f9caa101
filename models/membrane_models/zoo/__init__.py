"""Shipped models: ONNX graphs and their manifests (package data). See membrane_models.zoo_index for lookup."""
