"""The connection to CoppeliaSim: timeouts on our side and the add-on's."""

from __future__ import annotations

import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import SIM_TIMEOUT, lattice_on

from membrane_client import Client
from membrane_coppelia.film import run_film
from membrane_coppelia.link import SimulatorTimeout, connect_simulator
from membrane_coppelia.standin import CoppeliaStandin


def test_a_simulator_that_stops_answering_raises_a_clear_timeout(
    membrane_client: Client,
) -> None:
    with CoppeliaStandin(answer_limit=500) as hung:  # dies while the lattice is being built
        connection = connect_simulator("127.0.0.1", hung.port, timeout=0.3)
        try:
            with (
                pytest.raises(SimulatorTimeout, match=r"did not answer within 0.3 s"),
                lattice_on(connection, membrane_client) as lattice,
            ):
                run_film(lattice)
        finally:
            connection.close()
        assert hung.replies == 500


def test_nothing_listening_times_out() -> None:
    with CoppeliaStandin() as probe:  # a free port: bind one, then let it go
        port = probe.port
    with pytest.raises(SimulatorTimeout, match=rf"tcp://127.0.0.1:{port} did not answer"):
        connect_simulator("127.0.0.1", port, timeout=0.2)


def test_the_remote_timeout_is_sent_with_the_first_request(standin: CoppeliaStandin) -> None:
    link = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT, remote_timeout=7.5)
    try:
        (client,) = standin.protocol.snapshot().values()
        assert client.timeout == 7.5
    finally:
        link.close()
    assert standin.protocol.snapshot() == {}  # closing said goodbye (_*end*_): forgotten now
