r"""``ros2 run es_bringup bringup``: run the closed-loop node graph as separate processes.

Our own small replacement for ``ros2 launch`` (``launch/closed_loop.launch.py`` starts the
same graph: both take it from :func:`es_bringup.graph.build_graph`). It starts, from their
installed ``lib/<pkg>/<exe>`` launchers:

the recorder (``es_recordings record``) on every /dm topic and /diagnostics if a bag is asked for,
the thermal node and the feedforward node; once the graph shows their subscriptions, the
plant (lockstep, ``exit_when_done``), which itself waits until every topic it publishes has
a matched subscription from its peers and the recorder (``start_subscribers``) and until the
recorder, thermal and feedforward nodes report on /diagnostics that they are ready
(``wait_ready``): no fixed settle time.

It supervises them (:mod:`es_bringup.supervisor`): output goes to ``<log_dir>/<name>.log``
(and to the terminal with a ``[name]`` prefix unless ``--quiet``), a node that dies stops the
rest with a non-zero exit and a clear message, and when the plant finishes its scenario the
others are stopped (SIGINT, then SIGTERM, then SIGKILL, by PID), the recorder last, so that
its bag is closed with everything in it. Every node inherits ROS_DOMAIN_ID and the rest of
the environment.

Example::

    ros2 run es_bringup bringup --scenario thesis_ac --mode inverse_hyperbolic \
        --calibration out/calibration --bag out/thesis_ac

``--calibration DIR`` takes both files ``calibrate -o DIR`` wrote (the feedforward's and the
thermal node's); ``--feedforward-params`` / ``--thermal-params`` give them one by one. With
the thermal file the thermal node undoes the sensor's lag and the feedforward's lead is off
(:func:`es_bringup.calibration_files.temperature_lead_s`).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import NoReturn

from es_bringup.calibration_files import CalibrationFiles
from es_bringup.errors import CalibrationFilesError
from es_bringup.graph import (
    FEEDFORWARD,
    PLANT,
    RECORDED_TOPICS,
    RECORDER,
    TEST_STAND_TOPICS,
    THERMAL,
    GraphConfig,
    GraphError,
    NodeSpec,
    ParamValue,
    build_graph,
    namespaced_params_file,
    scenario_parameters,
    scoped,
    topic_remaps,
)
from es_bringup.graph_waits import DRAIN_IDLE_S, wait_for_recorder, wait_for_subscriptions
from es_bringup.invariants import recorder_counts_from_log, recorder_holes
from es_bringup.supervisor import EXIT_FAILURE, Outcome, ProcessSpec, StopTimeouts, Supervisor
from es_msgs_py import topics

__all__ = [
    "Bringup",
    "GraphConfig",
    "ParamValue",
    "namespaced_params_file",
    "node_specs",
    "run_graph",
    "scenario_parameters",
]

#: Longest wait for the recorder to catch up after the plant finished [s] (it
#: stops earlier when the recorder's counts stand still for ``graph_waits.DRAIN_IDLE_S``).
DRAIN_TIMEOUT_S = 60.0

#: What the nodes started before the plant subscribe to: the bring-up waits until the graph
#: shows these before it starts the plant (which then waits for their readiness reports).
SUBSCRIPTIONS: dict[str, tuple[str, ...]] = {
    RECORDER: RECORDED_TOPICS,
    THERMAL: (topics.TEMPERATURE_RAW, topics.HEAT_LOAD),
    FEEDFORWARD: (topics.SETPOINT, topics.TEMPERATURE),
}


def executable(package: str, name: str) -> Path:
    """Return the installed launcher ``<prefix>/lib/<package>/<name>`` (what ``ros2 run`` runs).

    The package's prefix comes from the ament index when it is set up (colcon install), else
    it is this interpreter's prefix (the virtual environment of a pip install).

    Raises:
        FileNotFoundError: the launcher is not installed.

    """
    candidates = []
    try:
        from ament_index_python.packages import get_package_prefix

        candidates.append(Path(get_package_prefix(package)))
    except (ImportError, LookupError, ValueError, OSError):
        pass
    candidates.append(Path(sys.prefix))
    for prefix in candidates:
        path = prefix / "lib" / package / name
        if path.is_file():
            return path
    raise FileNotFoundError(f"{package} {name} is not installed (looked in lib/{package}/)")


def ros_arguments(
    node_name: str,
    parameters: Mapping[str, ParamValue],
    params_files: Sequence[Path] = (),
    namespace: str | None = None,
) -> list[str]:
    """Return ``--ros-args`` for a node: name, namespace, parameter files, then parameters.

    Values are written as JSON, which the ROS argument parser reads as YAML: strings stay
    strings (quoted), lists become arrays, booleans ``true``/``false``. A ``namespace`` puts
    the node in ``/<namespace>`` and remaps every contract topic (absolute names, /clock
    and /diagnostics included) below it, so that graphs run side by side in one domain.
    """
    args = ["--ros-args", "-r", f"__node:={node_name}"]
    if namespace:
        args += ["-r", f"__ns:=/{namespace}"]
        for topic, remapped in topic_remaps(namespace):
            args += ["-r", f"{topic}:={remapped}"]
    for path in params_files:
        args += ["--params-file", str(path)]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={json.dumps(value)}"]
    return args


def node_specs(config: GraphConfig) -> tuple[list[ProcessSpec], ProcessSpec]:
    """Return the processes started before the plant (recorder first) and the plant.

    The nodes are :func:`es_bringup.graph.build_graph`'s, as ``ros2 launch`` starts them.

    Raises:
        GraphError: the graph cannot be built (scenario, parameters file).
        FileNotFoundError: a node's launcher is not installed.

    """
    graph = build_graph(config)
    before = [_process(node, config.namespace) for node in graph.before]
    return before, _process(graph.plant, config.namespace, primary=True)


def _process(node: NodeSpec, namespace: str | None, primary: bool = False) -> ProcessSpec:
    command = [
        str(executable(node.package, node.executable)),
        *node.arguments,
        *ros_arguments(node.name, node.parameters, node.params_files, namespace),
    ]
    # the recorder stops after every node it records
    return ProcessSpec(node.name, command, primary, stop_stage=1 if node.name == RECORDER else 0)


class Bringup:
    """One run of the graph; :meth:`interrupt` may be called from any thread.

    Args:
        config: what to run.
        echo: echo node output to stdout with a ``[name]`` prefix.
        timeouts: stop escalation timeouts.
        announce: receives the supervisor's one-line messages (default: stderr).

    """

    def __init__(
        self,
        config: GraphConfig,
        echo: bool = False,
        timeouts: StopTimeouts | None = None,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        self.config = config
        env = dict(os.environ)
        if config.domain_id is not None:
            env["ROS_DOMAIN_ID"] = str(config.domain_id)
        self.supervisor = Supervisor(
            config.log_dir,
            echo=sys.stdout if echo else None,
            timeouts=timeouts,
            env=env,
            announce=announce,
        )
        self._interrupted = threading.Event()

    def interrupt(self) -> None:
        """Stop the run as soon as possible (clean stop, exit code 130)."""
        self._interrupted.set()
        self.supervisor.interrupt()

    def run(self) -> Outcome:
        """Start the nodes, wait until the graph shows them, start the plant, supervise."""
        before, plant = node_specs(self.config)
        for spec in before:
            self.supervisor.start(spec)
        expected = {spec.name: SUBSCRIPTIONS[spec.name] for spec in before}
        if not self.config.with_controllers and RECORDER in expected:
            expected[RECORDER] = TEST_STAND_TOPICS
        if RECORDER in expected:
            expected[RECORDER] = (*expected[RECORDER], *self.config.record_extra)
        namespace = self.config.namespace
        problem = wait_for_subscriptions(
            {name: [scoped(t, namespace) for t in wanted] for name, wanted in expected.items()},
            self.config.ready_timeout, self.supervisor, self._interrupted,
            domain_id=self.config.domain_id, node_namespace=f"/{namespace}" if namespace else "/",
        )  # fmt: skip
        if problem is not None:
            outcome = self.supervisor.stop()
            outcome.reason = problem
            return outcome
        # No settle time: the plant's first step waits until the recorder, thermal and
        # feedforward nodes report on /diagnostics that their inputs are matched (wait_ready).
        self.supervisor.start(plant)
        drain = self._drain_recorder if self.config.bag is not None else None
        outcome = self.supervisor.run(wall_timeout=self.config.wall_timeout, on_primary_done=drain)
        if self.config.bag is not None:
            self._fail_on_holes(outcome)
        return outcome

    def _fail_on_holes(self, outcome: Outcome) -> None:
        """Make ``outcome`` a failure if the recorder closed its bag knowing of a hole.

        The recorder's closing log names, per topic, the published messages it knew it had
        not received (gaps in the publishers' sequence numbers, counts announced beyond
        them): a bag with a hole is no record of the run, whatever the exit codes say.
        """
        log = self.config.log_dir / f"{RECORDER}.log"
        if not log.is_file():
            return
        lines = log.read_text(encoding="utf-8", errors="replace").splitlines()
        closing = recorder_counts_from_log(lines)
        holes = recorder_holes(closing)
        # what the plant logged it published: an announcement on /diagnostics travels the
        # same way as the messages and can be lost with them
        plant_log = self.config.log_dir / f"{PLANT}.log"
        if plant_log.is_file():
            plant_lines = plant_log.read_text(encoding="utf-8", errors="replace").splitlines()
            published = plant_published_counts(plant_lines, closing)
            holes += [
                f"{topic}: plant published {sent}, recorder received {closing[topic].received}"
                for topic, sent in published.items()
                if topic in closing
                and closing[topic].received < sent
                and not closing[topic].not_received  # named above already
            ]
        if not holes:
            return
        for hole in holes:
            self.supervisor.announce(f"bag incomplete: {hole}")
        outcome.exit_code = outcome.exit_code or EXIT_FAILURE
        outcome.reason = f"{outcome.reason}; bag incomplete: {'; '.join(holes)}"

    def _drain_recorder(self) -> None:
        """Wait until the recorder has received everything the plant published.

        Nothing paces the plant by the recorder (a test stand by nobody, a lockstep plant by
        its controllers): the plant may run ahead of the recorder, whose deep queue
        (``--queue-depth``) holds the backlog. The recorder reports its received counts on
        /diagnostics every second; the plant's exit log has what it published.
        """
        log = self.config.log_dir / f"{PLANT}.log"
        lines = log.read_text(encoding="utf-8", errors="replace").splitlines()
        recorded = RECORDED_TOPICS if self.config.with_controllers else TEST_STAND_TOPICS
        published = plant_published_counts(lines, recorded)
        if not wait_for_recorder(
            published, DRAIN_TIMEOUT_S, self.config.domain_id, self.config.namespace
        ):
            self.supervisor.announce(
                f"recorder has not reported every published message (waited up to "
                f"{DRAIN_TIMEOUT_S:g} s, or {DRAIN_IDLE_S:g} s without progress); "
                "stopping it anyway"
            )


def plant_published_counts(plant_log: Iterable[str], recorded: Iterable[str]) -> dict[str, int]:
    """Return the plant's published counts of the /dm topics of ``recorded``.

    Only those: the recorder reports no count for a topic it does not record (a test stand
    records no set points, and it has no thermal node), so waiting for one never ends.
    """
    from es_bringup.invariants import published_counts_from_log

    counts = published_counts_from_log(plant_log, topics.TOPIC_TYPES)
    wanted = set(topics.DM_TOPICS) & set(recorded)
    return {t: n for t, n in counts.items() if t in wanted}




def run_graph(
    config: GraphConfig,
    echo: bool = False,
    timeouts: StopTimeouts | None = None,
    announce: Callable[[str], None] | None = None,
) -> Outcome:
    """Run the graph until the plant finishes its scenario; return how it ended.

    Call from the main thread: SIGINT/SIGTERM received by this process stop the graph
    cleanly (exit code 130). From other threads use :class:`Bringup` directly.
    """
    bringup = Bringup(config, echo, timeouts, announce)
    previous = {
        sig: signal.signal(sig, lambda _s, _f: bringup.interrupt())
        for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        return bringup.run()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parse_assignment(text: str) -> tuple[str, ParamValue]:
    """Parse ``name:=value`` (value as YAML, like ``ros2 run ... -p``)."""
    import yaml

    name, sep, raw = text.partition(":=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME:=VALUE, got {text!r}")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise argparse.ArgumentTypeError(f"cannot read the value of {text!r}") from None
    if not isinstance(value, bool | int | float | str | list):
        raise argparse.ArgumentTypeError(f"unsupported value in {text!r}")
    return name, value


def parse_args(argv: Sequence[str]) -> tuple[GraphConfig, bool]:
    """Parse the command line into a graph configuration and the echo flag."""
    parser = _OneLineParser(
        prog="bringup",
        description="Run plant, thermal, feedforward and recorder as supervised processes.",
    )
    parser.add_argument("--scenario", required=True, help="scenario name or YAML path")
    parser.add_argument(
        "--mode", default="inverse_hyperbolic", help="feedforward mode (see its --help)"
    )
    parser.add_argument("--feedforward-params", type=Path, help="parameters YAML for feedforward")
    parser.add_argument(
        "--thermal-params",
        type=Path,
        help="parameters YAML for the thermal node (a calibration's thermal_params.yaml)",
    )
    parser.add_argument(
        "--calibration",
        type=Path,
        metavar="DIR",
        help="a calibration's output directory: both parameters files are taken from it",
    )
    parser.add_argument("--bag", type=Path, help="record every /dm topic and /diagnostics here")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--log-dir", type=Path, default=Path("log/bringup"))
    parser.add_argument("--timeout", type=float, help="wall-clock limit of the run [s]")
    parser.add_argument(
        "--duration", type=float, help="run length [s of simulation]; default: the scenario's"
    )
    parser.add_argument(
        "--time-scale",
        type=float,
        help="multiplier of the scenario's slow (thermal) times, 1 = physical; default: the "
        "scenario's own",
    )
    parser.add_argument(
        "--namespace", help="run the graph below /NAMESPACE (topics remapped, bag keeps names)"
    )
    parser.add_argument("--quiet", action="store_true", help="node output to log files only")
    parser.add_argument(
        "--test-stand",
        action="store_true",
        help="plant and recorder only (a characterisation scenario drives its own voltages)",
    )
    for node in (PLANT, THERMAL, FEEDFORWARD):
        parser.add_argument(
            f"--{node}-param",
            dest=f"{node}_param",
            action="append",
            default=[],
            type=_parse_assignment,
            metavar="NAME:=VALUE",
            help=f"extra parameter of the {node} node (repeatable)",
        )
    ns = parser.parse_args(list(argv))
    try:
        files = CalibrationFiles.given(ns.calibration, ns.feedforward_params, ns.thermal_params)
    except CalibrationFilesError as err:
        parser.error(str(err))
    if ns.bag is not None and ns.bag.exists():
        parser.error(f"--bag: {ns.bag} exists already; a bag is never overwritten")
    config = GraphConfig(
        scenario=ns.scenario,
        mode=ns.mode,
        bag=ns.bag,
        log_dir=ns.log_dir,
        feedforward_params=files.feedforward,
        thermal_params=files.thermal,
        plant=dict(ns.plant_param),
        thermal=dict(ns.thermal_param),
        feedforward=dict(ns.feedforward_param),
        storage=ns.storage,
        with_controllers=not ns.test_stand,
        wall_timeout=ns.timeout,
        duration=ns.duration,
        time_scale=ns.time_scale,
        namespace=ns.namespace,
    )
    return config, not ns.quiet


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bring-up from the command line; return the exit code."""
    config, echo = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        outcome = run_graph(config, echo=echo)
    except (FileNotFoundError, GraphError) as err:
        print(f"bringup: error: {err}", file=sys.stderr)
        return 2
    status = "ok" if outcome.exit_code == 0 else "FAILED"
    print(f"[bringup] {status}: {outcome.reason}; logs in {config.log_dir}", file=sys.stderr)
    if config.bag is not None and outcome.exit_code == 0:
        print(f"[bringup] bag: {config.bag}", file=sys.stderr)
    return outcome.exit_code


if __name__ == "__main__":
    sys.exit(main())
