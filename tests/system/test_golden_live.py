"""Live regression tier: run the node graph over DDS again and compare with the golden bags.

Each golden case (es_sim_plant.golden) runs through the bring-up exactly as the golden bag
was made: plant, thermal and feedforward nodes in lockstep and the recorder. The new bag
must match the golden one:

- message counts of every /dm topic exactly;
- values of every /dm topic with ``np.allclose(rtol=1e-9, atol=ATOL)``, ATOL = 1e-15 m,
  1e-9 degC, 1e-9 V: lockstep makes the run deterministic (seeded plant, fixed message
  order per step), so only floating-point noise may differ;
- bag timestamps (the recorder's sim time at reception) non-decreasing and within the
  run's sim time span (they lag the plant's clock by up to a few tenths of a second: the
  recorder's /clock subscription is best effort and served between data messages, so they
  are not compared with the golden ones; the analysis pairs messages by index instead);
- the run's invariants: every command finite and within +-350 V, and every message the
  nodes published on a recorded topic is in the bag.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from es_msgs_py import topics
from es_msgs_py.bag import read_bag
from es_sim_plant.analysis import check_run, node_logs
from es_sim_plant.golden import CASES, GoldenCase, record

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
RTOL = 1e-9
ATOL = {
    topics.DISPLACEMENT: 1e-15,
    topics.SETPOINT: 1e-15,
    topics.HEAT_LOAD: 1e-15,
    topics.TEMPERATURE_RAW: 1e-9,
    topics.TEMPERATURE: 1e-9,
    topics.COMMAND: 1e-9,
}

pytestmark = pytest.mark.dds


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_live_run_matches_golden_bag(case: GoldenCase, tmp_path: Path) -> None:
    outcome = record(case, tmp_path, tmp_path / "logs")
    assert outcome.exit_code == 0, outcome.reason
    live = read_bag(tmp_path / case.name)
    golden = read_bag(GOLDEN / case.name)
    duration = case.load().duration
    for topic, atol in ATOL.items():
        new, old = live[topic], golden[topic]
        assert len(new) == len(old), f"{topic}: {len(new)} messages, golden has {len(old)}"
        assert new.values is not None and old.values is not None
        np.testing.assert_allclose(new.values, old.values, rtol=RTOL, atol=atol, err_msg=topic)
        assert np.all(np.diff(new.times) >= 0.0), topic
        assert 0.0 <= new.times[0] and new.times[-1] <= duration + 1e-9, topic
    invariants = check_run(live, node_logs(tmp_path / "logs" / case.name), v_limit=350.0)
    assert invariants.ok, invariants.failures
    assert invariants.command_count == len(golden[topics.COMMAND])
