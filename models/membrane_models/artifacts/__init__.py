"""What the server loads, without torch: model manifests, the shipped zoo's index, and the
evaluation of a model against its reference solution."""
