"""The cap on a request's head (request line and headers): a total and a per-line bound, checked on the raw
bytes before the HTTP parser sees them.

uvicorn's httptools parser keeps no bound of its own, and it grows a header value by appending each chunk
that arrives, so one endless header costs the server time that grows with the square of its size (a 92 MB
value took 9.7 s of CPU). :class:`HeadMeter` counts a head as it arrives, chunk by chunk, in time linear in
the chunk and without copying it: the connection guard (:mod:`service.http.connection_guard`) answers a head
past either bound with ``431`` and reads nothing more of that connection.
"""

from __future__ import annotations

_TEXT = b"request header fields too large"
HEADERS_TOO_LARGE_RESPONSE = (b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: text/plain; charset=utf-8"
                              b"\r\ncontent-length: " + str(len(_TEXT)).encode() + b"\r\nconnection: close\r\n\r\n"
                              + _TEXT)


class HeadMeter:
    """Bytes of the current request's head so far and of its current line; :meth:`feed` says when a bound
    is passed. ``max_total`` / ``max_line`` of 0 turn that bound off."""

    def __init__(self, max_total: int, max_line: int) -> None:
        self.max_total, self.max_line = max_total, max_line
        self.total = 0
        self.line = 0
        self._last = b""  # the chunk's last two bytes: a blank line split across chunks still ends the head

    def reset(self) -> None:
        """A new head starts (the parser saw the end of the last one)."""
        self.total = self.line = 0
        self._last = b""

    def feed(self, data: bytes) -> bool:
        """Count ``data``, the next bytes of a connection in its head; True when the head passes a bound.
        Bytes after the blank line that ends the head (a body, a pipelined request) are not counted."""
        end = _head_end(self._last, data)
        part = data if end < 0 else memoryview(data)[:end]
        size = len(part)
        self.total += size
        first = data.find(b"\n", 0, size)
        if first < 0:
            self.line += size
        else:
            last = data.rfind(b"\n", 0, size)
            longest = self.line + first
            if self.max_line and last - first > self.max_line:  # only then can a middle line be too long
                longest = max(longest, max(len(x) for x in bytes(part[first + 1:last]).split(b"\n")))
            self.line = size - last - 1
            if self.max_line and longest > self.max_line:
                return True
        over = bool((self.max_total and self.total > self.max_total) or (self.max_line and self.line > self.max_line))
        if end >= 0:
            self.reset()
        else:
            self._last = (self._last + data[-2:])[-2:]
        return over


def _head_end(last: bytes, data: bytes) -> int:
    """Where in ``data`` the head ends (just past its blank line: ``\\n\\n`` or ``\\n\\r\\n``), counting the
    bytes before it in ``last``; -1 when it does not end in ``data``."""
    joined = last + data[:2]  # a blank line that began in the previous chunk
    for marker in (b"\n\n", b"\n\r\n"):
        at = joined.find(marker)
        if at >= 0 and at + len(marker) > len(last):
            return at + len(marker) - len(last)
    ends = [at + len(marker) for marker in (b"\n\n", b"\n\r\n") if (at := data.find(marker)) >= 0]
    return min(ends) if ends else -1
