"""Live regression tier: run the node graph over DDS again and compare with the golden bags.

Each golden case (es_bringup.golden) runs through the bring-up as the golden bag was made
(plant, thermal and feedforward nodes in lockstep and the recorder), here with the graph
below a namespace as the demo runs it. The new bag must match the golden one:

- message counts of every /dm topic exactly;
- values of every /dm topic with ``np.allclose(rtol=1e-9, atol=ATOL)``: the plant's own
  outputs (set points, heat loads, raw temperatures) exactly (seeded), the estimates within
  1e-4 degC, commands within 1e-3 V and displacements within 1e-12 m (see ATOL: the only
  run-to-run freedom is the sim time at which the thermal node received a sample);
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

from es_bringup.analysis import check_run, node_logs
from es_bringup.golden import CASES, GoldenCase, record
from es_msgs_py import topics
from es_msgs_py.bag import read_bag

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
RTOL = 1e-9
#: The plant's outputs are seeded and exact; the thermal node advances its filter by the
#: sim time it received each sample at, which may lag by a step under load (its adaptive
#: terms then differ by ~1e-6 degC), and that reaches the commands and displacements.
ATOL = {
    topics.SETPOINT: 1e-15,
    topics.HEAT_LOAD: 1e-15,
    topics.TEMPERATURE_RAW: 1e-9,
    topics.TEMPERATURE: 1e-4,
    topics.COMMAND: 1e-3,
    topics.DISPLACEMENT: 1e-12,
}

pytestmark = pytest.mark.dds


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_live_run_matches_golden_bag(case: GoldenCase, tmp_path: Path) -> None:
    # in a namespace: the bag must still hold the contract's topic names
    outcome = record(case, tmp_path, tmp_path / "logs", namespace="live")
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
        assert new.times[0] >= 0.0, topic
        assert new.times[-1] <= duration + 1e-9, topic
    invariants = check_run(live, node_logs(tmp_path / "logs" / case.name), v_limit=350.0)
    assert invariants.ok, invariants.failures
    assert invariants.command_count == len(golden[topics.COMMAND])
