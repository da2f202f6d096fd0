"""The ROS domain picked for isolated runs stays below Linux's ephemeral ports."""

from __future__ import annotations

from pathlib import Path

from es_msgs_py.topics import MAX_SAFE_DOMAIN_ID, process_domain_id, reserve_domain_id


def test_process_domain_id_covers_1_to_the_safe_maximum() -> None:
    domains = {process_domain_id(pid) for pid in range(10_000)}
    assert domains == set(range(1, MAX_SAFE_DOMAIN_ID + 1))
    # domain d, participant p: unicast discovery port 7410 + 250 d + 2 p; in the top domain
    # the first 50 participants of a host stay below Linux's ephemeral range
    assert 7410 + 250 * MAX_SAFE_DOMAIN_ID + 2 * 50 < 32768


def test_reserved_domains_are_never_shared_while_held(tmp_path: Path) -> None:
    # a second reservation (another open file, as another process would have) skips the
    # domains held and wraps around within 1..MAX_SAFE_DOMAIN_ID
    first = reserve_domain_id(tmp_path)
    second = reserve_domain_id(tmp_path)
    assert first != second
    assert {first, second} <= set(range(1, MAX_SAFE_DOMAIN_ID + 1))
    assert second == 1 + first % MAX_SAFE_DOMAIN_ID
    others = {reserve_domain_id(tmp_path) for _ in range(MAX_SAFE_DOMAIN_ID - 2)}
    assert others | {first, second} == set(range(1, MAX_SAFE_DOMAIN_ID + 1))
    # every domain held: the PID's own domain, as without reservation
    assert reserve_domain_id(tmp_path) == process_domain_id()
