"""Which sample and which command each resonance sweep belongs to (pure, no rclpy).

Sweeps, sensor readings and commands reach the thermal node on different topics from
different nodes; :class:`SampleSync` puts them back together before
:class:`es_thermal.selfsensing.SelfSensingFusion` uses a sweep.
"""

from __future__ import annotations

from collections import deque
from typing import Final

import numpy as np

from es_common.arrays import FloatArray
from es_thermal.errors import ThermalInputError
from es_thermal.selfsensing import ChannelHealth, SelfSensingFusion

#: A sweep arriving this many sample periods after readings still without one belongs to
#: them; a sweep whose command is still unknown after this long is fused without waiting.
LATE_PERIODS: Final = 1.5
#: Commands kept to find the one a sweep ran under (several sample periods' worth).
COMMAND_HISTORY: Final = 256
#: Sweeps kept waiting for their command at most; beyond, the oldest is dropped (counted):
#: its command never comes (e.g. the command publisher's clock lags the plant's).
MAX_WAITING: Final = 64


class SampleSync:
    """Pairs every sweep with its sample's model estimate and the command it ran under.

    One sweep belongs to each sample: the plant publishes it just before the sample's
    readings, but sweeps, readings and commands are different topics from different nodes
    and may be handled in any order (an executor takes one message per topic and round, so
    a backlog of commands lags behind). Hence:

    - sample: a sweep that comes while the last sample's estimate still lacks its sweep
      (within :data:`LATE_PERIODS` periods of it) belongs to that sample; otherwise it waits
      for the next readings;
    - command: the sweep ran under the newest command *published* before it (publication
      stamps of one host's clock, ``source_ns``), which is known for sure once a command
      published after the sweep has been handled (messages of one topic come in order);
      until then the sweep waits. Only when no command at all has been handled for
      :data:`LATE_PERIODS` periods (commands stopped) is a sweep waiting that long fused with
      the newest command handled; while commands keep coming (a backlog of them draining,
      possibly far behind on a loaded machine) it waits for its own, since fusing it with an
      older command errs by the voltage term.

    A sweep fused after its sample's estimate went out corrects the following estimates
    (its correction is computed against its own sample's model estimate). Fusing a sweep
    with the next sample's estimate, or with the wrong command (-80 Hz/V: 1 V is 0.025
    degC), would err wherever temperature or voltage move.

    Args:
        fusion: the per-actuator fusion.
        sample_period: the sensor sample period [s].

    """

    def __init__(self, fusion: SelfSensingFusion, sample_period: float) -> None:
        self.fusion = fusion
        self.window = LATE_PERIODS * sample_period
        self._commands: deque[tuple[int, FloatArray]] = deque(maxlen=COMMAND_HISTORY)
        self._last_command: float | None = None  # arrival of the newest command [s]
        self._pending: tuple[int, float, FloatArray] | None = None  # source, arrival, sweep
        self._unpaired: tuple[float, float, FloatArray] | None = None  # stamp, arrival, model
        # sweeps with their sample, waiting for their command: (source, arrival, sweep,
        # stamp, model)
        self._waiting: deque[tuple[int, float, FloatArray, float, FloatArray]] = deque()
        #: Arrival time of the newest sweep [s] (None before the first).
        self.last_sweep: float | None = None
        #: The verdict on the newest sweep fused (None before the first).
        self.health: ChannelHealth | None = None
        #: Sweeps fused with their own estimate, after it, with a guessed command, and
        #: dropped unfused (their command never came, :data:`MAX_WAITING`).
        self.paired = {"in_order": 0, "late": 0, "without_command": 0, "dropped": 0}

    def on_command(
        self, source_ns: int, voltage: FloatArray, arrival: float | None = None
    ) -> None:
        """Take a command (R, C) or (N,) [V] published at ``source_ns`` [ns, host clock].

        ``arrival`` is the time it is handled [s] (the clock of the other ``arrival`` values);
        None: not known (commands then never count as still coming).

        Raises:
            ThermalInputError: wrong size or a non-finite value (the command is ignored).

        """
        self.fusion.set_command(voltage)
        self._commands.append((source_ns, self.fusion.voltage))
        self._last_command = arrival
        self._flush(None)

    def on_resonance(self, arrival: float, source_ns: int, frequency: FloatArray) -> None:
        """Take one sweep (R, C) or (N,) [Hz] published at ``source_ns``, arriving at ``arrival``.

        Raises:
            ThermalInputError: a sweep of the wrong size (nothing is updated).

        """
        sweep = np.asarray(frequency, float).ravel()
        if sweep.size != self.fusion.count:
            raise ThermalInputError(
                f"resonance has {sweep.size} values, expected {self.fusion.count}"
            )
        self.last_sweep = arrival
        unpaired = self._unpaired
        if unpaired is not None and abs(arrival - unpaired[1]) <= self.window:
            self._unpaired = None
            self._waiting.append((source_ns, arrival, sweep, unpaired[0], unpaired[2]))
            self._flush(arrival)
        else:
            self._pending = (source_ns, arrival, sweep)

    def on_estimate(self, stamp: float, arrival: float, model: FloatArray) -> FloatArray:
        """Fuse a sample's model estimate [degC] with what is known; return the result.

        ``stamp`` is the sample time [s], ``arrival`` the time the readings came [s].

        Raises:
            ThermalInputError: a model estimate of the wrong size.

        """
        flat = np.asarray(model, float)
        self._flush(arrival)
        pending, self._pending = self._pending, None
        self._unpaired = None if pending is not None else (stamp, arrival, flat)
        if pending is not None:
            self._waiting.append((pending[0], pending[1], pending[2], stamp, flat))
            self._flush(arrival, current=stamp)
        return self.fusion.fuse(stamp, flat, None)

    def restart(self) -> None:
        """Forget every correction and any sweep or estimate waiting for its partner."""
        self.fusion.restart()
        self._pending = None
        self._unpaired = None
        self._waiting.clear()

    def _command_at(self, source_ns: int) -> FloatArray | None:
        """Return the command published last before ``source_ns``, None while not sure."""
        if not self._commands or self._commands[-1][0] <= source_ns:
            return None
        before = [volts for stamp, volts in self._commands if stamp < source_ns]
        return before[-1] if before else np.zeros(self.fusion.count)

    def _flush(self, now: float | None, current: float | None = None) -> None:
        """Fuse the waiting sweeps, oldest first, whose command is known (or overdue).

        ``now`` is the arrival time of the message being handled (None: a command);
        ``current`` the stamp of the sample whose estimate is about to go out.
        """
        while len(self._waiting) > MAX_WAITING:
            self._waiting.popleft()
            self.paired["dropped"] += 1
        while self._waiting:
            source_ns, arrival, sweep, stamp, model = self._waiting[0]
            volts = self._command_at(source_ns)
            overdue = (
                now is not None
                and now - arrival > self.window
                and (self._last_command is None or now - self._last_command > self.window)
            )
            if volts is None and not overdue:
                return
            self._waiting.popleft()
            if volts is None:
                kind = "without_command"
            else:
                kind = "in_order" if stamp == current else "late"
            self.paired[kind] += 1
            self.fusion.fuse(stamp, model, sweep, volts)
            self.health = self.fusion.latest
