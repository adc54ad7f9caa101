"""The CoppeliaSim adapter (`membrane coppelia`): the served lattice as spheres in a running
CoppeliaSim, moved every simulation step; its Lua script; and a stand-in simulator that speaks
the ZeroMQ remote API's protocol, for tests and for trying the adapter without CoppeliaSim.

One concept per module:

- ``coppelia_link``: the connection (both sides' timeouts, errors, a fresh-connection release);
- ``coppelia_compat``: the call each CoppeliaSim version (4.6 to 4.10) has for each operation;
- ``coppelia``: the sphere lattice, and a film shown step by step;
- ``coppelia_probe``: a live session pressed by a scene object, its force written back;
- ``coppelia_interrupt``: SIGINT / SIGTERM end a run with the simulation stopped;
- ``coppelia_lua`` + ``coppelia_batch.lua``: the script that moves every sphere in one call;
- ``coppelia_cli``: the ``membrane coppelia`` command;
- ``coppelia_fakescene`` + ``coppelia_standin``: the stand-in (a scene playing one release,
  behind a model of the remote API add-on's loop).

Its own package (extra ``coppelia``), importing only ``membrane_client`` and ``membrane_cli``.
"""
