"""The CoppeliaSim adapter (`membrane coppelia`): the served lattice as spheres in a running
CoppeliaSim, moved every simulation step; its Lua script; and a stand-in simulator that speaks
the ZeroMQ remote API's protocol, for tests and for trying the adapter without CoppeliaSim.

One job per module:

- ``link``: the connection (both sides' timeouts, errors, calls on an unusable connection
  refused, a fresh-connection release);
- ``compat``: the call each CoppeliaSim version (4.6 to 4.10) has for each operation;
- ``lattice``: the spheres in the scene, built, moved (batched or sphere by sphere), removed;
- ``stepping``: the simulation in stepping mode, started, stepped and always stopped;
- ``film``: a film shown step by step (``drive_lattice``);
- ``probe``: a live session pressed by a scene object, its force written back (``drive_probe``);
- ``options``: ``RunOptions``, the settings both paths, the command and the examples share;
- ``results``: what a run reports (``RunResult``, ``ProbeRunResult``, ``StepTimings``);
- ``interrupt``: SIGINT / SIGTERM end a run with the simulation stopped;
- ``batch_script`` + ``batch_script.lua``: the script that moves every sphere in one call;
- ``cli``: the ``membrane coppelia`` command;
- ``standin/``: the stand-in, a test double (a scene playing one release, behind a model of the
  remote API add-on's loop), run with ``python -m membrane_coppelia.standin``.

Its own package (extra ``coppelia``), importing only ``membrane_client`` and ``membrane_cli``.
"""
