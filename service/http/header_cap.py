"""The cap on a request's head (request line and headers) and its trailers: a total and a per-line bound,
checked on the raw bytes before the HTTP parser sees them.

uvicorn's httptools parser keeps no bound of its own, and it grows a header value by appending each chunk
that arrives, so one endless header costs the server time that grows with the square of its size (a 92 MB
value took 9.7 s of CPU). The same holds for a chunked body's trailer fields, the headers after its last
(``0``) chunk. :class:`HeadMeter` counts a head as it arrives, chunk by chunk, in time linear in the chunk and
without copying it; :class:`BodyMeter` follows a body's framing (``Content-Length`` or chunked) to find where
it ends and where its trailers start, and counts the trailers against what is left of the head's cap (one
cap for every header byte of a request). The connection guard (:mod:`service.http.connection_guard`)
answers a head or trailers past either bound with ``431`` (or closes the connection, when the request was
already answered) and reads nothing more of that connection.
"""

from __future__ import annotations

import re

_TEXT = b"request header fields too large"
HEADERS_TOO_LARGE_RESPONSE = (b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: text/plain; charset=utf-8"
                              b"\r\ncontent-length: " + str(len(_TEXT)).encode() + b"\r\nconnection: close\r\n\r\n"
                              + _TEXT)


class HeadMeter:
    """Bytes of the current request's head so far and of its current line; :meth:`measure` says when a bound
    is passed. ``max_total`` / ``max_line`` of 0 turn that bound off. ``spent``: bytes already counted against
    the total (a request's head, for its trailers); ``after_line_end``: the meter starts just after a line's
    end (trailers), so that an empty first line ends it."""

    def __init__(self, max_total: int, max_line: int, spent: int = 0, after_line_end: bool = False) -> None:
        self.max_total, self.max_line = max_total, max_line
        self.total = spent
        self.line = 0
        self.finished = 0  # the total of the last head that ended
        self._last = b"\r\n" if after_line_end else b""  # the last two bytes: a blank line split across chunks

    def reset(self) -> None:
        """A new head starts (the parser saw the end of the last one)."""
        self.total = self.line = 0
        self._last = b""

    def feed(self, data: bytes) -> bool:
        """:meth:`measure` from the start of ``data``; only whether a bound was passed."""
        return self.measure(data)[0]

    def measure(self, data: bytes, start: int = 0) -> tuple[bool, int]:
        """Count ``data[start:]``, the next bytes of a connection in its head: (whether the head passed a bound,
        where in ``data`` it ends, just past its blank line, or -1). Bytes after that end (a body, a pipelined
        request) are not counted; at the end the meter starts again for the next head."""
        end = _head_end(self._last, data, start)
        stop = len(data) if end < 0 else end
        size = stop - start
        self.total += size
        first = data.find(b"\n", start, stop)
        if first < 0:
            self.line += size
        else:
            last = data.rfind(b"\n", start, stop)
            longest = self.line + first - start
            if self.max_line and last - first > self.max_line:  # only then can a middle line be too long
                longest = max(longest, max(len(x) for x in data[first + 1:last].split(b"\n")))
            self.line = stop - last - 1
            if self.max_line and longest > self.max_line:
                return True, end
        over = bool((self.max_total and self.total > self.max_total) or (self.max_line and self.line > self.max_line))
        if end >= 0:
            self.finished = self.total
            self.reset()
        else:
            self._last = (self._last + data[max(start, stop - 2):stop])[-2:]
        return over, end


def _head_end(last: bytes, data: bytes, start: int) -> int:
    """Where in ``data`` (from ``start``) the head ends (just past its blank line: ``\\n\\n`` or ``\\n\\r\\n``),
    counting the bytes before it in ``last``; -1 when it does not end in ``data``."""
    joined = last + data[start:start + 2]  # a blank line that began in the previous chunk
    for marker in (b"\n\n", b"\n\r\n"):
        at = joined.find(marker)
        if at >= 0 and at + len(marker) > len(last):
            return start + at + len(marker) - len(last)
    crlf = data.find(b"\n\r\n", start)
    stop = len(data) if crlf < 0 else crlf + 2  # a bare blank line counts only before it: no scan to the end
    lf = data.find(b"\n\n", start, stop)
    ends = [at + skip for at, skip in ((lf, 2), (crlf, 3)) if at >= 0]
    return min(ends) if ends else -1


_HEX = re.compile(rb"[0-9A-Fa-f]+")
_SIZE, _SIZE_LINE, _DATA, _DATA_END, _TRAILER = range(5)


class BodyMeter:
    """One request body's framing followed on the raw bytes, in time linear in them: a ``Content-Length``
    body (``length``) or a chunked one (``length`` None), whose size lines count against the per-line bound
    and whose trailers count against what ``head`` (the request's head, just measured) left of the caps."""

    def __init__(self, length: int | None, head: HeadMeter) -> None:
        self.chunked = length is None
        self.remaining = length or 0
        self.max_line = head.max_line
        self._state = _SIZE if self.chunked else _DATA
        self._digits = b""  # the chunk size read so far (its significant hex digits)
        self._line = 0  # bytes of the current chunk-size line
        self.trailer: HeadMeter | None = None
        self._head = head

    @property
    def in_trailer(self) -> bool:
        return self.trailer is not None

    def measure(self, data: bytes, start: int = 0) -> tuple[bool, int]:
        """Follow ``data[start:]``: (whether a size line or the trailers passed a bound, where in ``data`` the
        request ends, just past its body or its trailers, or -1)."""
        pos, size = start, len(data)
        while pos < size:
            if self._state == _TRAILER:  # trailer fields, up to the empty line that ends the request
                assert self.trailer is not None
                return self.trailer.measure(data, pos)
            if self._state == _DATA:
                pos = self._data(data, pos)
                if self.remaining:
                    return False, -1
                if not self.chunked:
                    return False, pos
                self._state = _DATA_END
            elif self._state == _DATA_END:  # the CRLF after a chunk's data
                lf = data.find(b"\n", pos)
                if lf < 0:
                    return False, -1
                pos, self._state, self._digits, self._line = lf + 1, _SIZE, b"", 0
            else:
                pos = self._size_line(data, pos)
            if self.max_line and self._line > self.max_line:
                return True, -1
        return False, -1

    def _data(self, data: bytes, pos: int) -> int:
        take = min(self.remaining, len(data) - pos)
        self.remaining -= take
        return pos + take

    def _size_line(self, data: bytes, pos: int) -> int:
        """Follow a chunk-size line (its hex digits, then any extensions up to its end); at its end the chunk's
        data, or the trailers after the last chunk, come next."""
        if self._state == _SIZE:
            match = _HEX.match(data, pos)
            if match is not None:
                self._digits = (self._digits + match.group()).lstrip(b"0")[-24:]
                self._line += match.end() - pos
                pos = match.end()
            if pos < len(data):
                self._state = _SIZE_LINE
            return pos
        lf = data.find(b"\n", pos)
        self._line += (len(data) if lf < 0 else lf + 1) - pos
        if lf < 0 or (self.max_line and self._line > self.max_line):
            return len(data)
        chunk = int(self._digits or b"0", 16)
        if chunk:
            self.remaining, self._state = chunk, _DATA
        else:
            self._state = _TRAILER
            self.trailer = HeadMeter(self._head.max_total, self.max_line, spent=self._head.finished,
                                     after_line_end=True)
        return lf + 1


def body_meter(headers: list[tuple[bytes, bytes]], head: HeadMeter) -> BodyMeter | None:
    """The meter of a request's body as its headers frame it (the parser refuses conflicting or bad framing):
    chunked with any ``Transfer-Encoding``, else ``Content-Length`` bytes; None without a body."""
    length = 0
    for name, value in headers:
        if name == b"transfer-encoding":
            return BodyMeter(None, head)
        if name == b"content-length" and value.strip().isdigit():
            length = int(value)
    return BodyMeter(length, head) if length else None
