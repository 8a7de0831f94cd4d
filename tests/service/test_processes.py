"""The topology tests' Redis and HAProxy: a port taken between choosing it and binding it is chosen again."""

from __future__ import annotations

import socket

import pytest

from tests.service.processes import HaproxyProcess, RedisProcess


@pytest.mark.slow  # starts haproxy
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


@pytest.mark.slow  # starts redis-server
def test_a_port_taken_before_redis_binds_it_is_chosen_again_and_a_restart_keeps_port_and_data() -> None:
    srv = RedisProcess()
    taken = srv.port
    blocker = socket.socket()
    blocker.bind(("127.0.0.1", taken))
    blocker.listen()  # accepts connections but never answers PING, as another program on the port would
    try:
        srv.start(timeout_s=20.0)
        assert srv.port != taken and srv.proc is not None and srv.proc.poll() is None
        with socket.create_connection(("127.0.0.1", srv.port), timeout=2.0) as sock:
            sock.sendall(b"SET k v\r\n")
            assert sock.recv(64).startswith(b"+OK")
        port = srv.port
        srv.stop()
        srv.start(timeout_s=20.0)
        assert srv.port == port
        with socket.create_connection(("127.0.0.1", srv.port), timeout=2.0) as sock:
            sock.sendall(b"GET k\r\n")
            assert sock.recv(64) == b"$1\r\nv\r\n"
    finally:
        blocker.close()
        srv.cleanup()
