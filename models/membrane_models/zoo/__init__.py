"""Shipped models: ONNX graphs and their manifests (package data).

Look them up with membrane_models.artifacts.zoo_index.
"""
