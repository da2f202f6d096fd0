"""Lockstep: hold a set point until the estimates of the sensor samples sent before it arrived.

In lockstep the plant publishes a step's raw temperatures, waits until the thermal node's
estimate reached its own subscription, and only then publishes the step's set point, which
must be computed with that estimate. The estimate and the set point come from different
writers, and DDS orders messages per writer only: the thermal node's writer hands the
estimate to its readers one after another, and under load it can be preempted after the
plant's reader, so the set point reaches the feedforward first. The feedforward therefore
counts the raw samples (sent by the set point's own publisher, before it) and the estimates
that answer them, and a set point that arrives while an estimate is owed waits, at most
``timeout`` wall seconds after its sample arrived (then the newest estimate is used and the
sample is counted as timed out).
"""

from __future__ import annotations

from collections import deque


class EstimateSync:
    """Count raw samples and estimates; say whether a set point must wait for an estimate.

    Times are wall seconds of one monotonic clock, given by the caller. An estimate that
    arrives before its raw sample (the two come from different writers too), or after its
    sample timed out, is kept as a credit for the next sample (as the lockstep plant's own
    wait for an estimate takes it).
    """

    def __init__(self, timeout: float) -> None:
        """Create the counter.

        Args:
            timeout: wall seconds an estimate may be owed, counted from its sample's arrival.

        Raises:
            ValueError: ``timeout`` is not positive and finite.

        """
        if not 0.0 < timeout < float("inf"):
            raise ValueError(f"timeout must be positive and finite, got {timeout!r}")
        self._timeout = timeout
        self._deadlines: deque[float] = deque()  # one per sample whose estimate is owed
        self._credit = 0  # estimates that came before their sample
        self.timed_out = 0  #: samples whose estimate did not come within the timeout

    def sample(self, now: float) -> None:
        """Note a raw sample's arrival at ``now``: its estimate is owed from now on."""
        if self._credit:
            self._credit -= 1
        else:
            self._deadlines.append(now + self._timeout)

    def estimate(self) -> None:
        """Note an estimate's arrival (valid or not: it is the answer to the oldest sample)."""
        if self._deadlines:
            self._deadlines.popleft()
        else:
            self._credit += 1

    def owed(self, now: float) -> bool:
        """Return whether an estimate is still owed at ``now``; expire overdue samples."""
        deadlines = self._deadlines
        while deadlines and deadlines[0] <= now:
            deadlines.popleft()
            self.timed_out += 1
        return bool(deadlines)

    @property
    def deadline(self) -> float | None:
        """Return when the oldest owed estimate stops being waited for (None: none owed)."""
        return self._deadlines[0] if self._deadlines else None
