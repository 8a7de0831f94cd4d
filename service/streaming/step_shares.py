"""Per-key shares of the step budget: which API key's characters step next, so that one key's many
characters cannot take the step thread's time from another key's few.

With shares on, every key's characters step in batches of their own (:mod:`service.streaming.lanes`),
each at most ``rows`` characters, and the scheduler asks this ledger who goes first:

* on a realtime tick, the key that has used the least step time goes first with all of its realtime
  batches; the batches of the other keys follow, most deserving first, each only while it ends before
  the next realtime tick is due; a key left out uses nothing, so it soon is the least served one and
  steps first. A key whose realtime characters cost more than the frame period so slows its own
  characters rather than the others' (beyond the step it takes on its turn);
* each asap step is one batch of the key that has used the least step time among the keys whose asap
  characters wait, so two asap keys get about equal time whatever their sizes.

Used time is counted per key in seconds of step. A key is never more than ``CREDIT_S`` behind the key
that used the most, so a key that sat idle (or stepped one character while another key stepped
hundreds) cannot bank credit and then take the thread for long. With shares off every character
belongs to the owner ``""`` and the ledger changes nothing: one batch per pace, as before.
"""

from __future__ import annotations

from collections.abc import Iterable

from service.streaming.step_length import smoothed

CREDIT_S = 0.25  # the most step time a key may be behind the busiest one


class StepShares:
    """Step time used per key, and the order the keys step in. Plain arithmetic on given seconds."""

    def __init__(self, enabled: bool, rows: int = 256) -> None:
        if rows < 1:
            raise ValueError(f"a key's batch must hold at least one character, got {rows}")
        self.enabled = enabled
        self.rows: int | None = rows if enabled else None  # most characters of one key in one batch
        self.used: dict[str, float] = {}
        self.asap_estimate: dict[str, float] = {}  # running length of one asap step, per key

    def owner(self, owner: str) -> str:
        """The key a character's steps are counted under: its own with shares on, else the common ``""``."""
        return owner if self.enabled else ""

    def charge(self, owner: str, seconds: float, asap: bool = False) -> None:
        """``owner``'s batch stepped for ``seconds``; an asap step also updates that key's step estimate."""
        if seconds < 0:
            raise ValueError(f"a step cannot take {seconds} s")
        self.used[owner] = self.used.get(owner, self._floor()) + seconds
        if asap:
            self.asap_estimate[owner] = smoothed(self.asap_estimate.get(owner) or None, seconds)

    def order(self, owners: Iterable[str]) -> list[str]:
        """``owners`` least used first (ties by name); none stays more than ``CREDIT_S`` behind the busiest."""
        wanted = set(owners)
        floor = self._floor()
        for k in wanted:
            self.used[k] = max(self.used.get(k, floor), floor)
        return sorted(wanted, key=lambda k: (self.used[k], k))

    def keep(self, owners: Iterable[str]) -> None:
        """Forget every key but ``owners`` (the keys with live characters): one that comes back starts afresh."""
        wanted = set(owners)
        for gone in [k for k in self.used if k not in wanted]:
            del self.used[gone]
        for gone in [k for k in self.asap_estimate if k not in wanted]:
            del self.asap_estimate[gone]

    def first(self, owners: Iterable[str]) -> str | None:
        """The key whose batch steps next among ``owners`` (None when there is none)."""
        ordered = self.order(owners)
        return ordered[0] if ordered else None

    def estimate(self, owner: str) -> float | None:
        """The running length of ``owner``'s asap step; None before one is seen."""
        value = self.asap_estimate.get(owner)
        return value if value else None

    def _floor(self) -> float:
        """Where a key joins and the least any key may hold: ``CREDIT_S`` below the busiest key."""
        return max(self.used.values(), default=0.0) - CREDIT_S if self.used else 0.0
