"""The CoppeliaSim adapter (`membrane coppelia`): the served lattice as spheres in a running
CoppeliaSim, moved every simulation step; its Lua script; and a stand-in simulator that speaks
the ZeroMQ remote API's protocol, for tests and for trying the adapter without CoppeliaSim.

Its own package (extra ``coppelia``), importing only ``membrane_client``.
"""
