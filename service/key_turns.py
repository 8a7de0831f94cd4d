"""Whose job goes next when several API keys' jobs wait for the same threads: the key that has used the least of
their time, so that one key's burst cannot hold another key's few jobs back.

A queue in front of a model's threads (:class:`service.work_queue.WorkQueue`: the HTTP work and the stream setup)
keeps each key's jobs in order, asks :meth:`KeyTurns.first` whose job takes a free thread, and charges each job's
time to its key when it ends. Two keys that both keep jobs waiting so get about equal thread time, whatever their
jobs' lengths; a key that comes back after a pause goes first, but it never counts more than ``CREDIT_S`` behind
the key that used the most, so it cannot take the threads for long on credit. With API keys off every job has the
one owner ``""`` and the order is first come, first served.

Plain arithmetic on given seconds (no clock, no threads): used from the event loop only.
"""

from __future__ import annotations

from collections.abc import Iterable

CREDIT_S = 0.25  # the most thread time a key may be behind the key that used the most


class KeyTurns:
    """Thread time used per key, and which waiting key goes next."""

    def __init__(self, credit_s: float = CREDIT_S) -> None:
        if credit_s < 0:
            raise ValueError(f"the credit cannot be negative, got {credit_s}")
        self.credit_s = credit_s
        self.used: dict[str, float] = {}

    def charge(self, owner: str, seconds: float) -> None:
        """A job of ``owner`` held a thread for ``seconds``."""
        if seconds < 0:
            raise ValueError(f"a job cannot take {seconds} s")
        self.used[owner] = self.used.get(owner, self._floor()) + seconds

    def first(self, waiting: Iterable[str]) -> str | None:
        """The key whose job goes next among ``waiting`` (given oldest job first: ties go to the earlier), or None
        when none waits."""
        owners = list(waiting)
        if not owners:
            return None
        floor = self._floor()
        for k in owners:
            self.used[k] = max(self.used.get(k, floor), floor)
        return min(owners, key=lambda k: self.used[k])  # min keeps the first of equals

    def tidy(self, active: Iterable[str]) -> None:
        """Forget the keys not in ``active`` (those with jobs waiting or running) that hold no more than the floor:
        one that comes back joins at the floor anyway. A key that was busy a moment ago is remembered, so that one
        sending a job at a time, each as the last ends, cannot take the threads on a fresh credit each time; and the
        ledger holds only the keys busy within the last ``credit_s`` of the others' thread time."""
        wanted = set(active)
        floor = self._floor()
        for gone in [k for k, used in self.used.items() if k not in wanted and used <= floor]:
            del self.used[gone]

    def _floor(self) -> float:
        """Where a key joins and the least any key may hold: ``credit_s`` below the key that used the most."""
        return max(self.used.values()) - self.credit_s if self.used else 0.0
