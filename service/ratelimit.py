"""Per-key token buckets: ``rate`` requests per second with bursts up to ``burst``; 429 + Retry-After beyond."""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable


class RateLimiter:
    """Token buckets keyed by API key (or client address). Used from the event loop only.

    The buckets are kept in the order they were last used, so each :meth:`take` costs the same however many
    keys are tracked: it drops, from the least recently used end, the buckets that have refilled (a full
    bucket is the same as none), and past ``max_keys`` the least recently used ones even if not yet full
    (such a key starts again with a full burst: the cap bounds memory, the rate still bounds each key).
    """

    def __init__(self, rate_per_s: float, burst: int, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 10_000) -> None:
        self.rate = rate_per_s
        self.burst = float(burst)
        self.clock = clock
        self.max_keys = max(1, max_keys)
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, last update)

    @property
    def enabled(self) -> bool:
        return self.rate > 0

    def __len__(self) -> int:
        return len(self._buckets)

    def take(self, key: str) -> float:
        """Spend one token; returns 0 when allowed, else the seconds until a token is available."""
        if not self.enabled:
            return 0.0
        now = self.clock()
        tokens, last = self._buckets.pop(key, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate)
        wait = 0.0
        if tokens >= 1.0:
            tokens -= 1.0
        else:
            wait = (1.0 - tokens) / self.rate
        self._buckets[key] = (tokens, now)  # the most recently used end
        self._prune(now)
        return wait

    def charge(self, key: str, cost: float) -> None:
        """Spend ``cost`` tokens at once, into debt if need be: work already done on the key's behalf (its
        later :meth:`take` calls wait until the debt is paid off)."""
        if not self.enabled or cost <= 0:
            return
        now = self.clock()
        tokens, last = self._buckets.pop(key, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate) - cost
        self._buckets[key] = (tokens, now)  # the most recently used end
        self._prune(now)

    def _prune(self, now: float) -> None:
        """Drop refilled buckets from the least recently used end (each is dropped once: O(1) amortized),
        then the oldest ones over the cap."""
        buckets = self._buckets
        full_after = self.burst / self.rate
        while buckets:
            tokens, last = next(iter(buckets.values()))
            if now - last < full_after - tokens / self.rate and len(buckets) <= self.max_keys:
                return
            buckets.popitem(last=False)


class TokenBucket:
    """One token bucket of ``rate_per_s`` tokens a second holding up to ``burst`` (default: one second's
    worth, at least 1); ``rate_per_s`` 0: no limit. For one connection's own budget, on the event loop."""

    def __init__(self, rate_per_s: float, burst: float | None = None) -> None:
        self.rate = rate_per_s
        self.burst = max(1.0, rate_per_s if burst is None else burst)
        self.tokens = self.burst
        self._last: float | None = None

    def take(self, now: float) -> float:
        """Spend one token at loop time ``now``: 0 when there was one, else the seconds until it is paid for
        (the token is spent in advance: whoever waits that long may go on)."""
        if self.rate <= 0:
            return 0.0
        if self._last is not None:
            self.tokens = min(self.burst, self.tokens + (now - self._last) * self.rate)
        self._last = now
        self.tokens -= 1.0
        return 0.0 if self.tokens >= 0 else -self.tokens / self.rate


def retry_after_header(wait_s: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(wait_s)))}
