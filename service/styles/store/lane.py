"""The style store's own threads, with their own timeout: store calls never run on a model's work threads.

A style store call may block (Redis: a round trip, or a whole timeout when Redis hangs). Run on a model's
single work thread, one such call held up every request queued behind it, those that never use the store
too. :class:`StoreLane` runs store calls (looking a ``style_id`` up, filing a registration, listing,
deleting) on a few threads of their own and answers ``style_store_unavailable`` (503, ``Retry-After``) once
``RSMT_STYLE_STORE_TIMEOUT_S`` has passed, whether or not the call has returned; a call that outlives its
answer finishes on its thread and its result is dropped. At most ``max_pending`` calls are in flight; past
that a call is refused at once with the same error, so a hung store costs a bounded number of threads and
requests, never the work queue.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from service.errors import ServiceError

log = logging.getLogger(__name__)
T = TypeVar("T")
RETRY_AFTER_S = 1


def store_unavailable(why: str) -> ServiceError:
    return ServiceError("style_store_unavailable", f"the style store {why}; registered styles are unavailable until "
                                                   "it answers again (requests with an inline or built-in style still "
                                                   "work); retry in a few seconds",
                        headers={"Retry-After": str(RETRY_AFTER_S)})


class StoreLane:
    """Style-store calls on ``threads`` threads of their own, each answered within ``timeout_s``."""

    def __init__(self, threads: int, timeout_s: float, max_pending: int = 64) -> None:
        self.timeout_s = timeout_s
        self.max_pending = max_pending
        self.pending = 0
        self._executor = ThreadPoolExecutor(threads, thread_name_prefix="style-store")

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on the lane; ``style_store_unavailable`` past the timeout or with the lane full."""
        if self.pending >= self.max_pending:
            raise store_unavailable(f"has {self.pending} calls outstanding (it is not answering)")
        self.pending += 1
        future = asyncio.get_running_loop().run_in_executor(self._executor, fn, *args)
        future.add_done_callback(self._done)
        try:
            return await asyncio.wait_for(asyncio.shield(future), self.timeout_s)
        except TimeoutError:
            raise store_unavailable(f"did not answer within {self.timeout_s:g} s (RSMT_STYLE_STORE_TIMEOUT_S)") from None

    def _done(self, future: asyncio.Future[Any]) -> None:
        self.pending -= 1
        if not future.cancelled() and future.exception() is not None and not isinstance(future.exception(), ServiceError):
            log.debug("a style store call failed", exc_info=future.exception())

    def shutdown(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)
