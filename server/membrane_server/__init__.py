"""membrane_server: the ZeroMQ inference daemon.

One concept per module: ``scene`` (scene files), ``source`` (what a scene's model names),
``runtime`` (onnxruntime sessions), ``evaluators`` (the four ways to answer a query),
``timeline`` (snapping and out-of-domain policy), ``dispatch`` (requests to replies),
``stats`` (counters and latency), ``server`` (the socket loop), ``cli`` (`membrane serve`).
Nothing is imported here, so `membrane --help` stays light.
"""
