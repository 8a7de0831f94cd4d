"""The Python client against a peer that takes each request and closes the connection without answering, as a
replica killed under the request does (tests/service/test_replicas.py kills real ones): every request is sent
again with the retry policy, except a DELETE, which might have taken effect already."""

from __future__ import annotations

import socket
import threading

import pytest
from rsmt_client import Client, RetryPolicy
from rsmt_client.errors import RsmtError


class DroppingPeer:
    """A 127.0.0.1 listener that reads each request's first bytes and closes; counts the connections."""

    def __init__(self) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self) -> DroppingPeer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(2)
                self.connections += 1
                try:
                    conn.recv(65536)
                except OSError:
                    pass


def test_a_dropped_request_is_sent_again_with_the_policy() -> None:
    with DroppingPeer() as peer, Client(peer.url, retry=RetryPolicy(attempts=3, backoff_s=0.01)) as client:
        with pytest.raises(RsmtError) as err:
            client.styles()
        assert err.value.code == "connection" and "without answering" in err.value.message
        assert peer.connections == 3


def test_a_dropped_delete_is_not_sent_again() -> None:
    with DroppingPeer() as peer, Client(peer.url, retry=RetryPolicy(attempts=3, backoff_s=0.01)) as client:
        with pytest.raises(RsmtError) as err:
            client.delete_style("sty_0123456789abcdef01234567")
        assert err.value.code == "connection"
        assert peer.connections == 1
