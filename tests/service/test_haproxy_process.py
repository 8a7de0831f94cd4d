"""The topology tests' HAProxy: a port taken between choosing it and binding it is chosen again."""

from __future__ import annotations

import socket

from tests.service.processes import HaproxyProcess


def test_a_port_taken_before_haproxy_binds_it_is_chosen_again() -> None:
    lb = HaproxyProcess([1])  # no replica needs to answer for haproxy to listen
    taken = lb.stats_port
    blocker = socket.socket()
    blocker.bind(("127.0.0.1", taken))
    blocker.listen()
    try:
        lb.start(timeout_s=20.0)
        assert lb.stats_port != taken and lb.proc is not None and lb.proc.poll() is None
        with socket.create_connection(("127.0.0.1", lb.port), timeout=2.0):
            pass
    finally:
        blocker.close()
        lb.cleanup()
