"""The load tester (`membrane bench`) and its echo baseline: latency, throughput and missed
deadlines of a running server, against a bare ZeroMQ echo measured in the same run.

Its own package (extra ``bench``: hdrhistogram, tqdm), importing only ``membrane_client``, so that
a simulator's Python that load-tests a server gets no server dependencies.
"""
