"""What one WebSocket connection may send: its message budgets, checked on each message before it is read.

A client that floods a connection with small messages (``ping`` in batches of thousands, never reading the
answers) would otherwise have every one parsed, validated and answered on the event loop, at a full core,
while other keys' streams starve. :class:`MessageBudget` bounds that before any of a message is parsed:

* **rate** (``RSMT_WS_MESSAGES_PER_S``): the connection's own token bucket, bursts of up to twice the rate;
* **queue** (``RSMT_WS_MAX_QUEUED_MESSAGES``): messages received but not yet handled (they wait behind a
  message still being handled, such as a ``start`` being prepared);
* **key** (``RSMT_WS_KEY_MESSAGES_PER_S``): every connection of one API key (one address without keys)
  together, each handshake counting one and a connection closed for flooding paying for the messages it
  left unread, so that reconnecting does not start a flood afresh: while the key's budget is spent its
  handshakes are answered 429, each after a wait of up to 2 s.

A connection past any of them is closed with 1008 at once (:func:`close_flooded`): reading stops, the close
frame is written and the socket closed, and one that does not leave within a second is aborted, so a flood
costs the loop a bounded amount of work however long the client keeps sending.
"""

from __future__ import annotations

import asyncio
from typing import Any

from service.errors import ServiceError
from service.ratelimit import TokenBucket, retry_after_header
from service.settings import Settings
from service.state import ServiceState
from service.streaming.connection import CLOSE_POLICY, Connection

#: A connection closed for flooding that has not left this long after its close frame is aborted.
_ABORT_AFTER_S = 1.0
#: The longest a handshake refused for a spent key budget waits for its 429.
_REFUSE_AFTER_MAX_S = 2.0


class MessageBudget:
    """The budgets of one connection of ``bucket`` (its API key, or its address without keys)."""

    def __init__(self, state: ServiceState, conn: Connection, bucket: str) -> None:
        settings: Settings = state.settings
        self.settings = settings
        self.conn = conn
        self.bucket = bucket
        self.shared = state.message_budgets
        self.own = TokenBucket(settings.ws_messages_per_s, 2 * settings.ws_messages_per_s)
        self._loop = asyncio.get_running_loop()

    @staticmethod
    async def admit(state: ServiceState, bucket: str) -> None:
        """Spend the handshake's token of the key's budget; raise ``rate_limited`` (429) when there is none,
        after waiting up to the time it takes to refill (at most a few seconds), so that a client reconnecting
        in a loop waits for its answers rather than costing a refusal per turn of its loop."""
        wait = state.message_budgets.take(bucket)
        if wait > 0:
            await asyncio.sleep(min(wait, _REFUSE_AFTER_MAX_S))
            rate = state.settings.ws_key_messages_per_s
            raise ServiceError("rate_limited", f"this API key's WebSocket connections sent over {rate:g} messages/s "
                                               f"together (RSMT_WS_KEY_MESSAGES_PER_S); reconnect in {wait:.2f} s and "
                                               "send fewer messages", headers=retry_after_header(wait))

    def spend(self) -> str | None:
        """Count one message just received, before it is read: None when it is within every budget, else why
        the connection is to be closed."""
        settings = self.settings
        if self.own.take(self._loop.time()) > 0:
            return (f"over {settings.ws_messages_per_s:g} messages/s on this connection (bursts of "
                    f"{2 * settings.ws_messages_per_s:g}; RSMT_WS_MESSAGES_PER_S): send fewer messages")
        waiting = _queued(self.conn) + 1  # this one too
        if waiting > settings.ws_max_queued_messages:
            return (f"{waiting} messages waiting to be handled, over {settings.ws_max_queued_messages} "
                    "(RSMT_WS_MAX_QUEUED_MESSAGES): wait for answers before sending more")
        if self.shared.take(self.bucket) > 0:
            return (f"this API key's connections sent over {settings.ws_key_messages_per_s:g} messages/s together "
                    "(RSMT_WS_KEY_MESSAGES_PER_S): send fewer messages")
        return None

    def charge_unread(self) -> None:
        """The connection is closed for going over a budget: the messages it had sent that wait unread were
        received and decoded all the same, so the key pays for them (a reconnecting flood finds its key's
        budget spent and its handshakes refused)."""
        self.shared.charge(self.bucket, _queued(self.conn))


def _queued(conn: Connection) -> int:
    """Messages uvicorn has received on ``conn`` that the route has not taken yet (0 under another server)."""
    transport = conn.transport()
    protocol: Any = transport.get_protocol() if transport is not None else None
    queue = getattr(protocol, "queue", None)
    return queue.qsize() if isinstance(queue, asyncio.Queue) else 0


async def close_flooded(conn: Connection, reason: str) -> None:
    """Close ``conn`` with 1008 and ``reason`` without reading another byte of it: reading stops first (the
    WebSocket protocol would read on until the client answers the close), then the close frame goes out and
    the socket is closed; a client that does not take it within a second is aborted."""
    transport = conn.transport()
    if transport is not None:
        transport.pause_reading()
    await conn.close(CLOSE_POLICY, reason)
    if transport is None or transport.is_closing():
        return
    transport.pause_reading()  # uvicorn resumes reading once it has sent a close frame
    transport.close()
    if transport.get_write_buffer_size():
        asyncio.get_running_loop().call_later(_ABORT_AFTER_S, transport.abort)
