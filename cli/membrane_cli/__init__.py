"""membrane_cli: the `membrane` command's dispatcher and the helpers every subcommand shares.

- ``dispatcher``: finds the subcommands each package registers, runs one, and turns the
  exception tree of ``membrane_errors`` into exit codes.
- ``arguments``: ``UsageError`` and the bounded number types argparse checks values with.
- ``connection``: the connection flags (address, timeout, CurveZMQ keys) and the Client they make.
- ``client_commands`` and ``keys_command``: `membrane query`, `ping`, `stats` and `keys`.

This ``__init__`` imports nothing: ``arguments`` must stay importable by the models package,
which may not reach the client.
"""
