"""The ROS domain picked for isolated runs stays below Linux's ephemeral ports."""

from __future__ import annotations

from es_msgs_py.topics import MAX_SAFE_DOMAIN_ID, process_domain_id


def test_process_domain_id_covers_1_to_the_safe_maximum() -> None:
    domains = {process_domain_id(pid) for pid in range(10_000)}
    assert domains == set(range(1, MAX_SAFE_DOMAIN_ID + 1))
    # domain d, participant p: unicast discovery port 7410 + 250 d + 2 p; in the top domain
    # the first 50 participants of a host stay below Linux's ephemeral range
    assert 7410 + 250 * MAX_SAFE_DOMAIN_ID + 2 * 50 < 32768
