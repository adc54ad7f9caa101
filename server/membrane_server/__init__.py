"""membrane_server: the ZeroMQ inference daemon."""
