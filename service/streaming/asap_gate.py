"""When the ``asap`` characters may step without making the ``realtime`` ones late.

Both groups step in one thread, one batch after the other. ``asap`` batches step back to back, so
one long ``asap`` step that starts just before a ``realtime`` tick is due delays that tick by up
to its whole length: 256 ``asap`` characters of one key slowed another key's real-time stream to
75% of its speed. The gate lets an ``asap`` step start only when, by the length of the last few, it
ends before the next ``realtime`` tick is due; a step that cannot end in time (a batch whose step is
longer than the gap) starts only on a budget that refills at ``share`` of the wall-clock time, so
real-time streams keep at least ``1 - share`` of their speed and ``asap`` streams still move on.
Without live ``realtime`` characters every ``asap`` step may start.
"""

from __future__ import annotations

from service.streaming.step_length import smoothed

MARGIN_S = 0.002  # an asap step must end this long before the realtime tick is due
BURST_S = 0.5  # the budget of late asap steps never holds more than this (no burst after a quiet spell)


class AsapGate:
    """The decision, kept apart from the loop so that it is plain arithmetic on given times (seconds)."""

    def __init__(self, share: float) -> None:
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"the asap share must be in [0, 1], got {share}")
        self.share = share
        self.estimate = 0.0  # running length of an asap step; 0 until one is seen
        self.credit = 0.0  # seconds of asap steps that may still make a realtime tick late
        self._last: float | None = None

    def fits(self, now: float, next_realtime: float | None, estimate: float | None = None) -> bool:
        """Whether an asap step started ``now`` ends before ``next_realtime`` (None: no realtime character);
        ``estimate``: the step's length when known better than the running one (one key's batch)."""
        return next_realtime is None or now + self._length(estimate) <= next_realtime - MARGIN_S

    def allows(self, now: float, next_realtime: float | None, estimate: float | None = None) -> bool:
        """Whether an asap step may start ``now``; refills the budget up to ``now``."""
        self._refill(now)
        if self.fits(now, next_realtime, estimate):
            return True
        return self.share > 0 and self.credit >= min(self._length(estimate), BURST_S * self.share)

    def _length(self, estimate: float | None) -> float:
        """The coming step's length: ``estimate`` when given, else the running one."""
        return self.estimate if estimate is None else estimate

    def record(self, seconds: float, fitted: bool) -> None:
        """An asap step took ``seconds``; one that did not fit (``fitted`` False) is paid from the budget."""
        if seconds < 0:
            raise ValueError(f"a step cannot take {seconds} s")
        self.estimate = smoothed(self.estimate or None, seconds)
        if not fitted:
            self.credit -= seconds

    def _refill(self, now: float) -> None:
        if self._last is not None and now > self._last:
            self.credit = min(BURST_S * self.share, self.credit + (now - self._last) * self.share)
        self._last = now if self._last is None else max(self._last, now)
