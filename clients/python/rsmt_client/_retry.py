"""Retries with backoff on 429 (honouring Retry-After) and 503, shared by every client: the policy and the
decisions of one request (:class:`Retrying`), with no I/O of their own."""

from __future__ import annotations

import email.utils
import random
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

RETRY_STATUSES = frozenset({429, 503})


def parse_retry_after(value: str | None, now: Callable[[], float] = time.time) -> float | None:
    """Seconds to wait from a ``Retry-After`` header: delta-seconds or an HTTP date; None when absent or unreadable."""
    if value is None:
        return None
    value = value.strip()
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when is None:
        return None
    return max(0.0, when.timestamp() - now())


@dataclass
class RetryPolicy:
    """How a client retries a request the server turned away for now.

    ``attempts`` counts every try (1: never retry). Without ``Retry-After`` the wait grows
    ``backoff_s * 2**n`` up to ``max_backoff_s``, with +-``jitter`` (a fraction) so that many
    clients do not return in step. A ``Retry-After`` is always honoured (plus a little jitter,
    never less) unless it is above ``max_retry_after_s``: then the error is raised at once, since
    waiting that long is the caller's decision. Refused connections (nothing was sent) are
    retried the same way, so a client may start before its server is up, and so are connections
    dropped before an answer (``retry_connect_errors`` covers both).
    """

    attempts: int = 5
    backoff_s: float = 0.25
    max_backoff_s: float = 8.0
    max_retry_after_s: float = 60.0
    jitter: float = 0.1
    statuses: frozenset[int] = field(default_factory=lambda: RETRY_STATUSES)
    retry_connect_errors: bool = True

    def backoff(self, retry: int) -> float:
        base = min(self.max_backoff_s, self.backoff_s * (2.0 ** retry))
        return max(0.0, base * (1.0 + random.uniform(-self.jitter, self.jitter)))

    def wait(self, retry: int, status: int | None, headers: Mapping[str, str] | None) -> float | None:
        """Seconds to wait before retry number ``retry`` (0-based), or None to give up.

        ``status`` None means a connection error.
        """
        if retry + 1 >= self.attempts:
            return None
        if status is None:
            return self.backoff(retry) if self.retry_connect_errors else None
        if status not in self.statuses:
            return None
        after = parse_retry_after((headers or {}).get("retry-after"))
        if after is None:
            return self.backoff(retry)
        if after > self.max_retry_after_s:
            return None
        return after * (1.0 + random.uniform(0.0, self.jitter))


NO_RETRY = RetryPolicy(attempts=1)


RetryHook = Callable[[int, float, Any], None]
"""Called before each wait as ``hook(retry, seconds, response)``; ``response`` is None after a refused connection."""


class Retrying:
    """The retry decisions of one request or handshake, for any transport (sans I/O).

    The transport tries; after each failure it asks :meth:`wait_or_raise` how long to sleep before
    the next try, and that raises the failure's error once the policy gives up.
    """

    def __init__(self, policy: RetryPolicy, on_retry: RetryHook | None = None) -> None:
        self.policy = policy
        self.on_retry = on_retry
        self.retry = 0

    def wait_or_raise(self, status: int | None, headers: Mapping[str, str] | None, error: Exception,
                      cause: BaseException | None = None, response: Any = None) -> float:
        """Seconds to wait after a failed try (``status`` None: no connection), or raise ``error`` from ``cause``."""
        wait = self.policy.wait(self.retry, status, headers)
        if wait is None:
            raise error from cause
        if self.on_retry is not None:
            self.on_retry(self.retry, wait, response)
        self.retry += 1
        return wait
