"""Per-channel Butterworth low-pass filter bank with state kept across samples.

The thesis low-pass filtered its NTC reading at about 0.1 Hz before the inverse model; this
bank does the same for every sensor at once (one second-order-section cascade, all channels
filtered by one ``scipy.signal.sosfilt`` call per sample).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from es_common.arrays import BoolArray, FloatArray
from es_thermal.errors import ThermalConfigError

#: The thesis's temperature filter: "noise and perturbation above about 0.1 Hz".
DEFAULT_CUTOFF_HZ = 0.1
DEFAULT_ORDER = 2


class LowpassBank:
    """Butterworth low-pass of ``order`` and ``cutoff_hz`` on ``channels`` parallel signals.

    The filter is discretised for a fixed ``sample_period``. A channel starts (or restarts,
    see :meth:`reset_channels`) in steady state at its first value, so there is no start-up
    transient from zero.
    """

    def __init__(
        self, channels: int, sample_period: float, cutoff_hz: float, order: int
    ) -> None:
        """Build the filter for ``channels`` inputs at ``sample_period`` [s] and ``cutoff_hz``.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        nyquist = 0.5 / sample_period
        if not 0.0 < cutoff_hz < nyquist:
            raise ThermalConfigError(
                f"low-pass cut-off {cutoff_hz} Hz must lie in (0, {nyquist:g}) Hz "
                f"(the Nyquist frequency of the {1.0 / sample_period:g} Hz sensor rate)"
            )
        if order < 1:
            raise ThermalConfigError(f"low-pass order must be >= 1, got {order}")
        self.channels = channels
        self.sos: FloatArray = signal.butter(
            order, cutoff_hz, btype="low", output="sos", fs=1.0 / sample_period
        )
        # Steady-state state for a unit input, shape (sections, 2); scaled per channel.
        self._zi_unit: FloatArray = signal.sosfilt_zi(self.sos)
        self._state: FloatArray = np.zeros((self.sos.shape[0], channels, 2))
        self._started: BoolArray = np.zeros(channels, bool)
        self._output: FloatArray = np.full(channels, np.nan)

    @property
    def output(self) -> FloatArray:
        """The latest filtered value of every channel (NaN before its first sample)."""
        return self._output.copy()

    def reset_channels(self, channels: BoolArray) -> None:
        """Forget the history of the marked channels: they restart at their next sample."""
        self._started &= ~np.asarray(channels, bool)

    def step(self, values: FloatArray, use: BoolArray) -> FloatArray:
        """Filter one sample of every channel marked in ``use`` and return all outputs.

        Channels not in ``use`` keep their state and their last output frozen.
        """
        use = np.asarray(use, bool)
        start = use & ~self._started
        if np.any(start):
            self._state[:, start, :] = self._zi_unit[:, None, :] * values[start][None, :, None]
            self._output[start] = values[start]
            self._started |= start
        inputs = np.where(use, values, 0.0)
        out, state = signal.sosfilt(self.sos, inputs[:, None], axis=1, zi=self._state)
        self._state = np.where(use[None, :, None], state, self._state)
        self._output = np.where(use, out[:, 0], self._output)
        return self.output
