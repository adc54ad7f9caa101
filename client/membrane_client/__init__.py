"""membrane_client: the thin client (pyzmq, msgpack, numpy only)."""
