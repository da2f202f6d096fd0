"""Fault injection into the thermal and feedforward node processes over DDS (wall time).

One graph for every case (process start-ups are the expensive part): thermal node, feedforward
node and recorder as processes, a watcher node in this process that checks every
/dm/command (layout, finite, within [0, v_limit]) and every /dm/temperature (finite). Cases:
hostile set points and temperatures, dead/stuck/out-of-range/missing sensors, hostile heat
loads, stale temperature, a burst of set points, parameters out of range at run time, the
recorder killed with SIGKILL. At the end no node may have died and every command the
feedforward published must be in the bag.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from support.ros import READY_TIMEOUT, NotReadyError, executable, poll_until

from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_msgs_py.arrays import grid_to_msg, sensors_to_msg
from es_msgs_py.bag import read_bag
from es_msgs_py.topics import (
    COMMAND,
    DIAGNOSTICS,
    HEAT_LOAD,
    SETPOINT,
    TEMPERATURE,
    TEMPERATURE_RAW,
)

from .graph import Proc, Watcher

if TYPE_CHECKING:
    from .conftest import FaultCases

pytestmark = pytest.mark.dds

SHAPE = (3, 3)
SENSORS = 9
TEMPERATURE_TIMEOUT = 1.5  # feedforward: wall seconds (no sim time here)
NM = 1e-9


def _ros_args(node: str, **params: object) -> list[str]:
    args = ["--ros-args", "-r", f"__node:={node}"]
    for name, value in params.items():
        args += ["-p", f"{name.replace('__', '.')}:={value}"]
    return args


@pytest.fixture
def graph(tmp_path: Path) -> Iterator[tuple[Watcher, dict[str, Proc], Path]]:
    bag = tmp_path / "bag"
    procs = {
        "record": Proc("record", [str(executable("es_recordings", "record")), "-o", str(bag),
                                  "--flush-interval", "0.2", COMMAND, SETPOINT, TEMPERATURE]),
        "thermal": Proc("thermal", [str(executable("es_thermal", "thermal_node")),
                                    *_ros_args("thermal", rows=3, cols=3,
                                               fault__stuck_time=0.3)]),
        "feedforward": Proc("feedforward", [
            str(executable("es_feedforward", "feedforward_node")),
            *_ros_args("feedforward", rows=3, cols=3, temperature_timeout=TEMPERATURE_TIMEOUT,
                       diagnostics_period=0.2, ready_subscribers=2)]),
    }
    watcher = Watcher(SHAPE)
    try:
        watcher.wait_matched({
            COMMAND: (1, 0),  # from the feedforward
            TEMPERATURE: (2, 3),  # thermal and watcher; feedforward, recorder and watcher
            DIAGNOSTICS: (3, 0),  # every node
            SETPOINT: (0, 2),  # feedforward and recorder
            TEMPERATURE_RAW: (0, 1),  # thermal
            HEAT_LOAD: (0, 1),  # thermal
        }, list(procs.values()))
        # Commands published before the recorder's subscription and the feedforward's
        # publisher have matched each other would be missing from the bag. Matching is
        # discovered on each side on its own: the recorder reports the publishers its
        # subscriptions matched, the feedforward is ready once its /dm/command publisher
        # matched ready_subscribers=2 subscriptions (watcher and recorder).
        wanted = {COMMAND: 1, SETPOINT: 1, TEMPERATURE: 2}

        def recorder_matched() -> bool:
            with watcher.lock:
                status = watcher.diagnostics.get("record: bag")
                ready = watcher.diagnostics.get("feedforward: ready")
            values = {} if status is None else {kv.key: kv.value for kv in status.values}
            return ready is not None and ready.message == "ready" and all(
                int(values.get(f"{t} publishers", "0")) >= n for t, n in wanted.items()
            )

        poll_until(recorder_matched, f"recorder report of matched publishers {wanted} and "
                                     "feedforward ready (its /dm/command matched 2 subscribers)")
        yield watcher, procs, bag
    finally:
        watcher.close()
        for proc in procs.values():
            proc.stop()


class Injector:
    """The steps the cases are made of."""

    def __init__(self, watcher: Watcher, rng: np.random.Generator) -> None:
        self.w = watcher
        self.rng = rng
        self.setpoints_sent = 0

    def setpoint(self, msg: Float64MultiArray) -> np.ndarray | None:
        """Send one set point; return the command it caused (None: none within 5 s)."""
        before = self.w.command_count()
        self.w.publish(SETPOINT, msg)
        self.setpoints_sent += 1
        if not self.w.wait_for(lambda: self.w.command_count() > before, READY_TIMEOUT):
            return None
        with self.w.lock:
            return None if self.w.commands.last is None else self.w.commands.last.copy()

    def good_setpoint(self) -> np.ndarray | None:
        return self.setpoint(grid_to_msg(self.rng.uniform(20, 120, SHAPE) * NM))

    def raw(self, readings: np.ndarray | Float64MultiArray, heat: np.ndarray | None = None,
            expect_estimate: bool = True) -> bool:
        """Send heat load and readings to the thermal node; return if an estimate came."""
        before = self.w.temperatures
        if heat is not None:
            self.w.publish(HEAT_LOAD, grid_to_msg(heat))
        msg = readings if isinstance(readings, Float64MultiArray) else sensors_to_msg(readings)
        self.w.publish(TEMPERATURE_RAW, msg)
        # an estimate comes within the bounded wait; a rejected reading gets none (checked for
        # 0.4 s: absence cannot be waited for)
        return self.w.wait_for(lambda: self.w.temperatures > before,
                               READY_TIMEOUT if expect_estimate else 0.4)

    def use_temperature(self, temperature: np.ndarray) -> None:
        """Inject an estimate and wait until the feedforward computes with it: probe set
        points until one's command is the core's for that temperature (a handshake; the
        probe is small enough for any v_limit the cases set).

        Raises:
            NotReadyError: no probe's command showed the estimate within READY_TIMEOUT.

        """
        core = Feedforward(FeedforwardConfig(shape=SHAPE))
        core.update_temperature(temperature, 0.0)
        probe = np.full(SHAPE, 20 * NM)
        expected = core.command(probe, 0.0).voltage
        self.w.publish(TEMPERATURE, grid_to_msg(temperature))
        deadline = time.monotonic() + READY_TIMEOUT
        command = self.setpoint(grid_to_msg(probe))
        while command is None or not np.allclose(command, expected):
            if time.monotonic() > deadline:
                raise NotReadyError(f"the feedforward never computed with {temperature.flat[0]} "
                                    f"degC: probe command {command}, expected {expected}")
            command = self.setpoint(grid_to_msg(probe))

    def readings(self) -> np.ndarray:
        return 45.0 + 0.05 * self.rng.standard_normal(SENSORS)


def _bag_commands(bag: Path) -> int:
    """Commands readable from a bag still being written (0: none yet)."""
    try:
        return len(read_bag(bag, [COMMAND])[COMMAND])
    except (ValueError, KeyError):
        return 0


def _message(watcher: Watcher, status_name: str) -> str:
    with watcher.lock:
        status = watcher.diagnostics.get(status_name)
    return "" if status is None else str(status.message)


def _bad_grid(**change: object) -> Float64MultiArray:
    msg = grid_to_msg(np.full(SHAPE, 50 * NM))
    if "data" in change:
        msg.data = change["data"]
    if "offset" in change:
        msg.layout.data_offset = change["offset"]
    if "dims" in change:
        msg.layout.dim = change["dims"]
    return msg


def test_faults_into_thermal_and_feedforward_nodes(
    graph: tuple[Watcher, dict[str, Proc], Path], fault_cases: FaultCases
) -> None:
    watcher, procs, bag = graph
    inject = Injector(watcher, np.random.default_rng(10))
    area = "nodes over DDS"

    # Baseline: readings through the thermal node give a computed (non-zero) command. The
    # watcher cannot see whether the thermal node's writer has matched the feedforward's
    # reader: until one estimate got through, the feedforward holds 0 V (a handshake: retry).
    first = None
    estimated = False
    deadline = time.monotonic() + READY_TIMEOUT
    while not (first is not None and np.all(first > 0.0)) and time.monotonic() < deadline:
        estimated = inject.raw(inject.readings(), heat=np.zeros(SHAPE))
        first = inject.good_setpoint()
    assert estimated
    assert first is not None and np.all(first > 0.0), (
        procs["feedforward"].output()[-800:], procs["thermal"].output()[-800:],
        watcher.diagnostics)

    # --- set points -------------------------------------------------------------------------
    nan_grid = np.full(SHAPE, 50 * NM)
    nan_grid[1, 1] = np.nan
    setpoint_cases: dict[str, Float64MultiArray] = {
        "set point all NaN": grid_to_msg(np.full(SHAPE, np.nan)),
        "set point one NaN": grid_to_msg(nan_grid),
        "set point +inf": grid_to_msg(np.full(SHAPE, np.inf)),
        "set point -inf": grid_to_msg(np.full(SHAPE, -np.inf)),
        "set point negative": grid_to_msg(np.full(SHAPE, -1e-6)),
        "set point huge (1e300 m)": grid_to_msg(np.full(SHAPE, 1e300)),
        "set point beyond reach (1 mm)": grid_to_msg(np.full(SHAPE, 1e-3)),
        "set point wrong length": _bad_grid(data=[50 * NM] * 8),
        "set point wrong layout (1 x 9)": grid_to_msg(np.full((1, 9), 50 * NM)),
        "set point sensor layout": sensors_to_msg(np.full(9, 50 * NM)),
        "set point data_offset 1": _bad_grid(offset=1),
        "set point swapped labels": _bad_grid(dims=[
            MultiArrayDimension(label="col", size=3, stride=9),
            MultiArrayDimension(label="row", size=3, stride=3)]),
        "set point empty message": Float64MultiArray(),
    }
    for name, msg in setpoint_cases.items():
        command = inject.setpoint(msg)
        fault_cases.expect(area, name, command is not None and procs["feedforward"].alive(),
                           "one finite command per set point expected")

    # --- temperatures straight into the feedforward -----------------------------------------
    temperature_cases: dict[str, Float64MultiArray] = {
        "temperature all NaN": grid_to_msg(np.full(SHAPE, np.nan)),
        "temperature one +inf": grid_to_msg(np.where(np.eye(3) > 0, np.inf, 45.0)),
        "temperature -300 degC": grid_to_msg(np.full(SHAPE, -300.0)),
        "temperature 1e6 degC": grid_to_msg(np.full(SHAPE, 1e6)),
        "temperature wrong length": sensors_to_msg(np.full(8, 45.0)),
        "temperature empty message": Float64MultiArray(),
    }
    for name, msg in temperature_cases.items():
        watcher.publish(TEMPERATURE, msg)
        command = inject.good_setpoint()
        fault_cases.expect(area, name, command is not None and procs["feedforward"].alive())
    assert inject.raw(inject.readings())  # a good estimate again

    # --- sensors through the thermal node ---------------------------------------------------
    dead = inject.readings()
    dead[4] = np.nan
    out_of_range = inject.readings()
    out_of_range[0], out_of_range[1] = -300.0, 1e6
    for name, readings in (("dead sensor (NaN)", dead), ("sensor -inf", np.where(
            np.arange(SENSORS) == 2, -np.inf, inject.readings())),
            ("sensors out of range (-300, 1e6 degC)", out_of_range)):
        got = inject.raw(readings)
        fault_cases.expect(area, name, got and procs["thermal"].alive(),
                           "a finite estimate from the other sensors expected")
    stuck_ok = True
    for _ in range(8):  # sensor 3 repeats one value for longer than fault.stuck_time
        readings = inject.readings()
        readings[3] = 44.0
        stuck_ok &= inject.raw(readings)
        watcher.wait_for(lambda: False, 0.05)  # the scenario: the value stays for > 0.3 s
    fault_cases.expect(area, "stuck sensor", stuck_ok and procs["thermal"].alive())
    for name, msg in (("sensors all NaN", sensors_to_msg(np.full(SENSORS, np.nan))),
                      ("sensor message wrong length", sensors_to_msg(np.full(8, 45.0))),
                      ("sensor message grid layout", grid_to_msg(np.full(SHAPE, 45.0))),
                      ("sensor message empty", Float64MultiArray())):
        got = inject.raw(msg, expect_estimate=False)
        fault_cases.expect(area, name, not got and procs["thermal"].alive(),
                           "no estimate published (no valid reading) expected")
    for name, heat in (("heat load NaN", np.full(SHAPE, np.nan)),
                       ("heat load wrong shape", np.zeros((2, 2)))):
        got = inject.raw(inject.readings(), heat=heat)
        fault_cases.expect(area, name, got and procs["thermal"].alive())

    # --- stale temperature: the feedforward holds its last good command ---------------------
    assert inject.raw(inject.readings())
    good = inject.good_setpoint()
    watcher.wait_for(lambda: False, TEMPERATURE_TIMEOUT + 0.5)  # the scenario: it goes stale
    held = inject.good_setpoint()
    fault_cases.expect(area, "stale temperature (no estimate for longer than the timeout)",
                       good is not None and held is not None and np.array_equal(good, held),
                       "the last good command held")
    # the diagnostic follows the command it explains: wait for it
    diagnosed = watcher.wait_for(lambda: "stale" in _message(watcher, "feedforward: temperature"),
                                 READY_TIMEOUT)
    fault_cases.expect(area, "stale temperature diagnosed", diagnosed,
                       _message(watcher, "feedforward: temperature"))
    # from here on an estimate must not go stale between its handshake and the set points
    # that need it (a burst takes seconds on a loaded machine): a far timeout at run time
    (fresh,) = watcher.set_parameters("feedforward", [Parameter("temperature_timeout",
                                                                value=600.0)])
    assert fresh[0], fresh[1]

    # --- burst of set points faster than the node processes ---------------------------------
    temperature = np.full(SHAPE, 46.0)
    inject.use_temperature(temperature)
    burst = [grid_to_msg(np.full(SHAPE, (20 + k % 100) * NM)) for k in range(299)]
    final = np.linspace(10, 150, 9).reshape(SHAPE) * NM
    burst.append(grid_to_msg(final))
    before = watcher.command_count()
    for msg in burst:
        watcher.publish(SETPOINT, msg)
    inject.setpoints_sent += len(burst)
    settled = watcher.wait_for(lambda: watcher.command_count() - before >= len(burst),
                               READY_TIMEOUT)
    core = Feedforward(FeedforwardConfig(shape=SHAPE))
    core.update_temperature(temperature, 0.0)
    expected = core.command(final, 0.0).voltage
    with watcher.lock:
        last = watcher.commands.last
        answered = watcher.commands.received - before
    fault_cases.expect(
        area, f"burst of {len(burst)} set points",
        procs["feedforward"].alive() and last is not None and np.allclose(last, expected),
        f"{answered} commands (all answered: {settled}); the last set point's command expected")

    # --- parameters out of range at run time: rejected with a reason ------------------------
    rejected = {
        "v_limit 5000 V": Parameter("v_limit", value=5000.0),
        "v_limit as a string": Parameter("v_limit", value="high"),
        "mode unknown": Parameter("mode", value="bogus"),
        "law.L negative": Parameter("law.L", value=[-1.0]),
        "law.m2 NaN": Parameter("law.m2", value=[float("nan")]),
        "law.k2 of the wrong length": Parameter("law.k2", value=[1e-6, 1e-6]),
        "temperature_timeout negative": Parameter("temperature_timeout", value=-1.0),
        "rows changed (read-only)": Parameter("rows", value=5),
        "observer.iterations 0": Parameter("observer.iterations", value=0),
        "observer.tolerance -1 V": Parameter("observer.tolerance", value=-1.0),
        "compensation.coupling 0.5": Parameter("compensation.coupling", value=0.5),
    }
    outcomes = watcher.set_parameters("feedforward", list(rejected.values()))
    for name, (successful, reason) in zip(rejected, outcomes, strict=True):
        fault_cases.expect(area, f"parameter {name}", not successful and bool(reason.strip()),
                           f"successful={successful}, reason={reason!r}")
    thermal_rejected = {
        "thermal rows changed (read-only)": Parameter("rows", value=4),
        "thermal sample_rate 0": Parameter("sample_rate", value=0.0),
    }
    outcomes = watcher.set_parameters("thermal", list(thermal_rejected.values()))
    for name, (successful, reason) in zip(thermal_rejected, outcomes, strict=True):
        fault_cases.expect(area, f"parameter {name}", not successful and bool(reason.strip()),
                           f"successful={successful}, reason={reason!r}")
    (accepted,) = watcher.set_parameters("feedforward", [Parameter("v_limit", value=100.0)])
    inject.use_temperature(temperature)
    limited = inject.setpoint(grid_to_msg(np.full(SHAPE, 200 * NM)))
    fault_cases.expect(area, "v_limit lowered to 100 V at run time",
                       accepted[0] and limited is not None and float(limited.max()) <= 100.0,
                       f"max {None if limited is None else float(limited.max())} V")

    # --- a heat load of absurd magnitude into the thermal node (last: it may kill it) -------
    huge = inject.raw(inject.readings(), heat=np.full(SHAPE, 1e12))
    after = inject.raw(inject.readings(), heat=np.zeros(SHAPE))
    fault_cases.expect(area, "heat load 1e12 W", procs["thermal"].alive(),
                       f"estimates after it: {huge}, {after}; thermal log tail: "
                       + procs["thermal"].output()[-300:].replace("\n", " | "))

    # --- the recorder killed with SIGKILL: its bag is readable up to its last flush ---------
    for name in ("feedforward", "thermal"):
        if not procs[name].alive():
            fault_cases.crashed()
    ff_exit = procs["feedforward"].stop()
    published = procs["feedforward"].published(COMMAND)
    # SIGKILL once everything is flushed: then nothing may be missing (a loss counts below)
    with contextlib.suppress(NotReadyError):
        poll_until(lambda: _bag_commands(bag) == published, f"{published} commands flushed")
    # what the recorder last reported (1 s period): "missed" counts commands published before
    # its subscription got the first one (or lost in gaps), which a loss at the stop is not
    with watcher.lock:
        status = watcher.diagnostics.get("record: bag")
    report = {} if status is None else {kv.key: kv.value for kv in status.values}
    procs["record"].kill()
    try:
        recorded = len(read_bag(bag, [COMMAND])[COMMAND])
        readable = True
    except ValueError as err:
        recorded, readable = 0, False
        fault_cases.expect(area, "bag after SIGKILL readable", False, str(err))
    if readable:
        fault_cases.expect(area, "bag after recorder SIGKILL readable", True)
    lost = (published or 0) - recorded
    fault_cases.expect(area, "every published command in the bag (recorder SIGKILLed)",
                       published is not None and lost == 0,
                       f"feedforward published {published}, bag holds {recorded}; the "
                       f"recorder last reported {report.get(f'{COMMAND} received')} received, "
                       f"{report.get(f'{COMMAND} missed')} missed")
    fault_cases.lost(max(lost, 0))
    fault_cases.expect(area, "feedforward exits cleanly at the end", ff_exit == 0,
                       f"exit code {ff_exit}")

    with watcher.lock:
        check = watcher.commands
        fault_cases.commands(check.received, check.non_finite, check.out_of_limit)
        fault_cases.expect(area, "every /dm/command finite, in limits, contract layout",
                           check.non_finite == check.out_of_limit == check.bad_layout == 0,
                           "; ".join(check.problems[:5]))
    bad_estimates = watcher.estimator_non_finite_temperatures()
    fault_cases.expect(area, "every /dm/temperature of the thermal node finite",
                       bad_estimates == 0, f"{bad_estimates} of {watcher.temperatures}")
    implausible = watcher.estimator_implausible_temperatures()
    fault_cases.expect(area, "every /dm/temperature of the thermal node within -50..200 degC",
                       implausible == 0, f"{implausible} of {watcher.temperatures} beyond")
    fault_cases.assert_held()
