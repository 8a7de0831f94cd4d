"""The raw-byte meters and budgets behind issue 64's items 1, 2 and 5, without a server (the fast tier): a
chunked body's framing is followed wherever the reads split it and its trailers share the head's caps; the
per-connection token bucket; a WebSocket read stops decoding once its queue is over budget; and keys in
percent-encoded query pairs and text are redacted."""

from __future__ import annotations

import asyncio
import random
from urllib.parse import quote

import pytest

from service.http.header_cap import BodyMeter, HeadMeter, body_meter
from service.http.log_redaction import REDACTED, redact, redact_keys
from service.http.ws_read_budget import SLICE_BYTES, feed_within_queue
from service.ratelimit import RateLimiter, TokenBucket

HEAD = b"POST /v1/transition HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
CHUNKED = b"5\r\nhello\r\n3;name=value\r\nabc\r\n10\r\n" + b"x" * 16 + b"\r\n0\r\nX-Sum: 1\r\nX-Other: 2\r\n\r\n"


def _follow(body: bytes, length: int | None, cuts: list[int], max_total: int = 1024, max_line: int = 256) -> tuple:
    """Feed ``body`` to a fresh meter (after HEAD) in the pieces ``cuts`` make: ("end", offset), ("over",) or ("open",)."""
    head = HeadMeter(max_total, max_line)
    assert head.measure(HEAD) == (False, len(HEAD))
    meter = BodyMeter(length, head)
    offset = 0
    for start, stop in zip([0, *cuts], [*cuts, len(body)]):
        over, end = meter.measure(body[:stop], start)  # the offsets of one buffer, as the guard passes them
        if over:
            return ("over",)
        if end >= 0:
            return ("end", end)
        offset = stop
    return ("open", offset)


@pytest.mark.parametrize("seed", range(40))
def test_a_chunked_body_ends_where_it_ends_however_the_reads_split_it(seed):
    rng = random.Random(seed)
    data = CHUNKED + b"GET /next HTTP/1.1\r\n"
    cuts = sorted(rng.sample(range(1, len(data)), rng.randint(0, 8)))
    assert _follow(data, None, cuts) == ("end", len(CHUNKED))


def test_a_content_length_body_ends_after_its_length():
    assert _follow(b"0123456789GET", 10, [3, 7]) == ("end", 10)
    assert _follow(b"01234", 10, []) == ("open", 5)


def test_trailers_share_the_heads_caps():
    trailer = b"0\r\nX-Flood: " + b"a" * 300 + b"\r\n\r\n"
    assert _follow(trailer, None, [], max_line=256) == ("over",)  # one line past the per-line cap
    many = b"0\r\n" + b"X-Many: 0123456789\r\n" * 40 + b"\r\n"  # 800 bytes: with the head's 70, past 800 in all
    assert _follow(many, None, [], max_total=800, max_line=0) == ("over",)
    assert _follow(many, None, [], max_total=1024, max_line=0) == ("end", len(many))
    assert _follow(b"0\r\n\r\n", None, []) == ("end", 5)  # no trailers at all


def test_an_endless_chunk_size_line_passes_the_line_cap():
    assert _follow(b"1;" + b"e" * 300, None, [100, 200]) == ("over",)
    assert _follow(b"0" * 300 + b"\r\n\r\n", None, []) == ("over",)


def test_body_framing_comes_from_the_headers():
    head = HeadMeter(0, 0)
    assert body_meter([(b"host", b"x")], head) is None
    assert body_meter([(b"content-length", b"0")], head) is None
    cl = body_meter([(b"content-length", b"12")], head)
    assert cl is not None and not cl.chunked and cl.remaining == 12
    te = body_meter([(b"transfer-encoding", b"chunked")], head)
    assert te is not None and te.chunked


def test_the_token_bucket_allows_its_burst_then_its_rate():
    bucket = TokenBucket(10.0)  # bursts of 10
    assert [bucket.take(0.0) for _ in range(10)] == [0.0] * 10
    assert bucket.take(0.0) == pytest.approx(0.1)  # the 11th is paid for by waiting
    assert bucket.take(0.2) == 0.0  # refilled meanwhile
    assert TokenBucket(0.0).take(0.0) == 0.0  # no limit


def test_a_charge_puts_the_key_in_debt():
    limiter = RateLimiter(100.0, 200, clock=lambda: 0.0)
    limiter.charge("k", 1000)
    assert limiter.take("k") == pytest.approx(8.01)  # 801 tokens short at 100 a second
    assert limiter.take("other") == 0.0


class _Protocol(asyncio.Protocol):
    """A WebSocket protocol that queues one message per 10 bytes it is given."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue = asyncio.Queue()
        self.fed = 0
        self.transport = _Transport()

    def data_received(self, data: bytes) -> None:
        self.fed += len(data)
        for _ in range(len(data) // 10):
            self.queue.put_nowait({"type": "websocket.receive"})


class _Transport:
    paused = False

    def pause_reading(self) -> None:
        self.paused = True


def test_a_websocket_read_stops_decoding_past_its_queue_budget():
    protocol = _Protocol()
    feed_within_queue(protocol, b"m" * (20 * SLICE_BYTES), 1000, protocol.data_received)
    assert protocol.fed == 2 * SLICE_BYTES  # 819 messages after one slice, 1638 after two: over 1000
    assert protocol.transport.paused
    within = _Protocol()
    feed_within_queue(within, b"m" * (3 * SLICE_BYTES), 10_000, within.data_received)
    assert within.fed == 3 * SLICE_BYTES and not within.transport.paused


KEY = "meter-test-key-0123456789abcdef"


def test_percent_encoded_keys_and_token_names_are_redacted():
    redact_keys([KEY])
    encoded = "".join(f"%{b:02x}" for b in KEY.encode())
    for line in (f"GET /v1/model?%74oken={encoded} HTTP/1.1", f"/v1/stream?encoding=json&%54%4F%4B%45%4E={encoded}",
                 f"/v1/styles/{encoded}", f"/x?q={quote(quote(KEY, safe=''), safe='')}", f"/x?token={KEY}"):
        clean = redact(line)
        assert REDACTED in clean and KEY not in clean and encoded not in clean, clean
    assert redact("/v1/x?%74oken=whatever&b=2") == f"/v1/x?%74oken={REDACTED}&b=2"  # any value of a token pair
    assert redact("/v1/x?name=caf%C3%A9&b=2") == "/v1/x?name=caf%C3%A9&b=2"  # other encoded text is left alone
