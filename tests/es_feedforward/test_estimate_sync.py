"""EstimateSync: which estimates a lockstep set point must wait for (pure, fake clock)."""

from __future__ import annotations

import pytest

from es_feedforward.estimate_sync import EstimateSync


def test_a_sample_owes_an_estimate_until_it_arrives() -> None:
    sync = EstimateSync(timeout=1.0)
    assert not sync.owed(0.0)
    assert sync.deadline is None
    sync.sample(10.0)
    assert sync.owed(10.5)
    assert sync.deadline == 11.0
    sync.estimate()
    assert not sync.owed(10.6)
    assert sync.timed_out == 0


def test_estimates_answer_samples_oldest_first() -> None:
    sync = EstimateSync(timeout=1.0)
    sync.sample(0.0)
    sync.sample(0.2)
    sync.estimate()
    assert sync.owed(0.3)
    assert sync.deadline == 1.2
    sync.estimate()
    assert not sync.owed(0.3)


def test_an_estimate_before_its_sample_is_a_credit() -> None:
    # the estimate and the raw sample come from different writers: either may be first
    sync = EstimateSync(timeout=1.0)
    sync.estimate()
    sync.sample(0.0)
    assert not sync.owed(0.0)
    sync.sample(0.1)  # the credit was used up: this one is owed
    assert sync.owed(0.1)


def test_an_overdue_estimate_stops_being_waited_for_and_is_counted() -> None:
    sync = EstimateSync(timeout=0.5)
    sync.sample(0.0)
    sync.sample(0.4)
    assert sync.owed(0.49)
    assert sync.owed(0.5)  # the first expired, the second is still owed
    assert sync.timed_out == 1
    assert not sync.owed(0.9)
    assert sync.timed_out == 2
    # a late estimate is a credit for the next sample, as the plant's own wait takes it
    sync.estimate()
    sync.sample(1.0)
    assert not sync.owed(1.0)


@pytest.mark.parametrize("timeout", [0.0, -1.0, float("inf"), float("nan")])
def test_timeout_must_be_positive_and_finite(timeout: float) -> None:
    with pytest.raises(ValueError, match="timeout"):
        EstimateSync(timeout)
