"""Retries with backoff on 429 (honouring Retry-After) and 503, shared by every client."""

from __future__ import annotations

import email.utils
import random
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

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
    retried the same way, so a client may start before its server is up.
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
