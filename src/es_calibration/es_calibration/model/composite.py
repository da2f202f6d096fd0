"""The calibration's composite forward model: hyperbolic law plus the candidate effects.

One evaluation predicts the displacement of a block of actuators at a set of samples together
with its Jacobians: per-actuator ("local") law coefficients and effect parameters shared by
all actuators ("global"). Which effects exist and what their unknowns are come from the
effect registry (:mod:`es_physics.effects`); each effect acts in one stage (its
:class:`~es_physics.effects.Role`), in this order:

- ``TEMPERATURE``: T_a = T + tau dT/dt (the actuator leads the sensor by a first-order lag);
- ``HEATING``: T_a += g LP_tau(P), P the effect's drive signal (the drive's loss), g,
  log tau and the signal's own parameters (self-heating: its running-mean window) fitted
  (the low-pass runs over the whole command, see history.py);
- ``INPUT_SHIFT``: V(t - d), applied when the inputs are built (see ``FitInputs``);
- ``PLAY``: V_eff = V + a(T_a) sum_i weight_i (play_(r_i)(V) - V),
  a(T_a) = exp(-beta (T_a - T_mean)) with beta fitted too; the play operators are applied
  when the inputs are built;
- ``RELAXATION``: V_eff -= r (V - LP_tau(V)), tau = 1 / (2 pi f_c), r and log f_c fitted
  (side by side with the play: their product is left out);
- ``LAW``: quadratic T* terms m3, k3 in M(T*) and k(T*) (two more local coefficients);
- ``GAIN``: M_eff = M (1 - f (1 - exp(-(t / tau)^nu))), t from the start of the data;
- ``SPATIAL``: z = z_free + c lap(z_free), 4-neighbour Laplacian, edges use only existing
  neighbours;
- ``ADDITIVE``: any number of terms added to z, each the effect's own
  :meth:`~es_physics.effects.Effect.additive` (e.g. alpha (T_a - T_mean) + offset).

Local coefficients are ``[m2, m1, k2, k1]`` (+ the ``LAW`` effect's, + the shared unknowns
fitted per actuator, ``per_actuator``: an effect's :attr:`~es_physics.effects.Effect.
local_options` of the roles ``TEMPERATURE`` and ``HEATING``); L and Tm are fixed
(they are not separately identifiable from displacement data). The coupling Jacobian keeps only
each actuator's own law coefficients (neighbours' cross terms are of order c and dropped), which
still converges to the least-squares fit for the small coefficients a face sheet produces.
Global parameters are named ``<effect>.<parameter>``.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from es_calibration.errors import CalibrationError
from es_calibration.model.cache import cache_bypassed
from es_calibration.model.history import DriveSamples, Filtered
from es_common.arrays import BoolArray, FloatArray, IndexArray
from es_feedforward.kernels import Backend, default_backend
from es_physics.effects import Effect, EffectError, Role, candidates, get, with_role
from es_physics.effects.coupling import neighbour_count, neighbour_laplacian
from es_physics.effects.drift import DRIFT_LOG_NU_LIMIT
from es_physics.params import ActuatorParams

#: Canonical names of the candidate effects (the registry's), in the order they are listed.
CANDIDATES: Final = candidates()
LINEAR_LAW: Final = ("m2", "m1", "k2", "k1")


@dataclass(frozen=True)
class FitInputs:
    """Measured data of a block of A actuators at n samples, ready for the model.

    Attributes:
        t: seconds since the start of the data, shape (n,).
        voltage: command in effect at each sample (after any delay), shape (A, n) [V].
        play: play operators of the (delayed) command, shape (K, A, n) [V], or None.
        temperature: measured temperature, shape (A, n) [degC].
        temperature_rate: its time derivative, shape (A, n) [degC/s].
        displacement: measured displacement, shape (A, n) [m].
        valid: samples that enter the cost, shape (A, n).
        grid: (rows, cols) of the block (row-major), used by the coupling Laplacian.
        mean_temperature: mean temperature of the whole data set [degC].
        drive: the command history read at these samples (for ``HEATING`` and
            ``RELAXATION`` effects), or None.

    """

    t: FloatArray
    voltage: FloatArray
    play: FloatArray | None
    temperature: FloatArray
    temperature_rate: FloatArray
    displacement: FloatArray
    valid: BoolArray
    grid: tuple[int, int]
    mean_temperature: float
    drive: DriveSamples | None = None


@dataclass(frozen=True)
class Evaluation:
    """Model prediction and Jacobians: (A, n), (A, n, P) and (A, n, G)."""

    prediction: FloatArray
    jac_local: FloatArray
    jac_global: FloatArray


class _LastTanh:
    """tanh(k V / L) of the last evaluation, by model, inputs and parameters (one slot).

    A Levenberg-Marquardt step evaluates its trial point without Jacobians and, once
    accepted, the same point again with them: the tanh (the law's costliest operation,
    numpy's, ~7 ms on 64 x 6000 values) is reused then. The slot holds weak references
    (a dead model or input never matches a new one at the same address) and one array;
    :func:`~es_calibration.model.cache.bypassed` switches it off.
    """

    def __init__(self) -> None:
        self._slot: tuple[weakref.ref[CompositeModel], weakref.ref[FitInputs], bytes,
                          FloatArray] | None = None

    @staticmethod
    def _key(local: FloatArray, g: FloatArray) -> bytes:
        return np.ascontiguousarray(local, np.float64).tobytes() + np.ascontiguousarray(
            g, np.float64).tobytes() + str(np.shape(local)).encode()

    def get(self, model: CompositeModel, data: FitInputs, local: FloatArray,
            g: FloatArray) -> FloatArray | None:
        """Return the kept tanh of exactly these model, inputs and parameters, or None."""
        slot = self._slot
        if slot is None or cache_bypassed():
            return None
        owner, inputs, key, th = slot
        if owner() is model and inputs() is data and key == self._key(local, g):
            return th
        return None

    def put(self, model: CompositeModel, data: FitInputs, local: FloatArray, g: FloatArray,
            th: FloatArray) -> None:
        """Keep ``th`` for these model, inputs and parameters (replacing the last one)."""
        if not cache_bypassed():
            th.flags.writeable = False
            self._slot = (weakref.ref(model), weakref.ref(data), self._key(local, g), th)


_last_tanh = _LastTanh()


class CompositeModel:
    """Hyperbolic law with a set of effects switched on; see the module docstring."""

    def __init__(
        self,
        effects: Sequence[str],
        base: ActuatorParams | None = None,
        operators: int = 1,
        per_actuator: Sequence[str] = (),
    ) -> None:
        """Build the model for ``effects`` (canonical names); L and Tm come from ``base``.

        ``operators`` is the number of play operators of the ``PLAY`` effect;
        ``per_actuator`` the ``<effect>.<parameter>`` unknowns fitted one per actuator.

        Raises:
            UnknownEffectError: a name no registered effect has.
            EffectError: an effect that is no calibration candidate, or a per-actuator
                unknown that no chosen effect offers as one.

        """
        chosen = [get(name) for name in effects]
        for effect in chosen:
            if not effect.candidate:
                raise EffectError(f"effect {effect.name} has no calibration model")
        self.effects: tuple[str, ...] = tuple(effects)
        base = base or ActuatorParams()
        self.L = float(np.asarray(base.L).ravel()[0])
        self.Tm = float(np.asarray(base.Tm).ravel()[0])
        self.lead = with_role(Role.TEMPERATURE, self.effects)
        self.heating = with_role(Role.HEATING, self.effects)
        self.relaxation = with_role(Role.RELAXATION, self.effects)
        #: the effect that shifts the command in time, and the play effect (or None)
        self.shift = with_role(Role.INPUT_SHIFT, self.effects)
        self.play = with_role(Role.PLAY, self.effects)
        self.law = with_role(Role.LAW, self.effects)
        self.gain = with_role(Role.GAIN, self.effects)
        self.spatial = with_role(Role.SPATIAL, self.effects)
        self.additive: tuple[Effect, ...] = tuple(e for e in chosen if e.role is Role.ADDITIVE)
        self.operators = operators if self.play else 0
        offered = {
            f"{e.name}.{p}"
            for e in (self.lead, self.heating)
            if e is not None
            for p in e.local_options
        }
        for key in per_actuator:
            if key not in offered:
                raise EffectError(f"{key} cannot be fitted per actuator in this model")
        self.per_actuator: tuple[str, ...] = tuple(per_actuator)
        self.local_names = (
            LINEAR_LAW + (self.law.local_parameters if self.law else ()) + self.per_actuator
        )
        self.global_names: tuple[str, ...] = tuple(
            f"{e.name}.{p}"
            for e in chosen
            for p in self.parameter_names(e)
            if f"{e.name}.{p}" not in self.per_actuator
        )

    def parameter_names(self, effect: Effect) -> tuple[str, ...]:
        """Return the effect's shared unknowns in this model (the play's: one per operator)."""
        return effect.fit_names(self.operators if effect is self.play else 1)

    def has(self, effect: str) -> bool:
        """Return whether ``effect`` is switched on."""
        return effect in self.effects

    def _global(self, g: FloatArray, effect: Effect, index: int = 0) -> float:
        return float(g[self.global_names.index(self.key(effect, index))])

    def _value(
        self, local: FloatArray, g: FloatArray, effect: Effect, index: int = 0
    ) -> FloatArray | float:
        """Return a shared unknown, or (A, 1) values when it is fitted per actuator."""
        key = self.key(effect, index)
        if key in self.per_actuator:
            j = self.local_names.index(key)
            return np.asarray(local[:, j : j + 1], np.float64)
        return self._global(g, effect, index)

    def key(self, effect: Effect, index: int = 0) -> str:
        """Return the global name of the effect's ``index``-th fit parameter."""
        return f"{effect.name}.{self.parameter_names(effect)[index]}"

    def _lowpass(
        self, data: FitInputs, effect: Effect, log_tau: float, g: FloatArray
    ) -> Filtered:
        """Return the effect's filtered drive signal at the samples and its derivatives.

        By log tau, and by each signal parameter (the effect's last shared unknowns, their
        values in ``g``).
        """
        if data.drive is None:
            raise CalibrationError(f"{effect.name} needs the command history in the inputs")
        first = len(self.parameter_names(effect)) - len(effect.signal_parameters)
        shape = [self._global(g, effect, first + i) for i in range(len(effect.signal_parameters))]
        # a time constant beyond e^+-30 s is no physical one (and would overflow)
        return data.drive.lowpass(effect, float(np.exp(np.clip(log_tau, -30.0, 30.0))), shape)

    def _law(  # noqa: PLR0917 - the numpy twin of law_loop.fused_law
        self,
        Ts: FloatArray,
        V: FloatArray,
        local: FloatArray,
        jacobian: bool,
        dTa: dict[str, FloatArray],
        dV_dTa: FloatArray | None,
        jac_l: FloatArray,
        th: FloatArray | None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Return H, dH/dV, dH/dT* and tanh(k V / L); write the law's columns into ``jac_l``.

        dH/dV and dH/dT* are 0.0 where they are not needed (no Jacobian; no ``dTa``);
        ``th``, when given, is that tanh already computed.
        """
        m2, m1, k2, k1 = (local[:, i : i + 1] for i in range(4))
        curved = self.law is not None
        m3 = local[:, 4:5] if curved else 0.0
        k3 = local[:, 5:6] if curved else 0.0
        M = m2 + Ts * (m1 + Ts * m3)
        k = k2 + Ts * (k1 + Ts * k3)
        if th is None:
            th = np.tanh(k * V / self.L)
        dH_dM = self.L / (k * k) * th * th
        H = M * dH_dM
        dH_dT: FloatArray | float = 0.0
        dH_dV: FloatArray | float = 0.0
        if jacobian:
            # th (1 - th^2) M / k: shared by the slope dz/dV and dz/dk
            slope_part = M * th * (1.0 - th * th) / k
            dH_dk = (V * slope_part - H) * (2.0 / k)
            dH_dV = 2.0 * slope_part
            columns = [dH_dM, dH_dM * Ts, dH_dk, dH_dk * Ts]
            if curved:
                columns += [dH_dM * Ts * Ts, dH_dk * Ts * Ts]
            for i, col in enumerate(columns):
                jac_l[..., i] = col
            if dTa:
                dH_dT = dH_dM * (m1 + 2.0 * m3 * Ts) + dH_dk * (k1 + 2.0 * k3 * Ts)
                if dV_dTa is not None:
                    dH_dT = dH_dT + dH_dV * dV_dTa
        return np.asarray(H, np.float64), np.asarray(dH_dV), np.asarray(dH_dT), th

    def evaluate(
        self, local: FloatArray, g: FloatArray, data: FitInputs, jacobian: bool = True
    ) -> Evaluation:
        """Return the prediction and Jacobians for local (A, P) and global (G,) parameters.

        With ``jacobian=False`` only the prediction is computed (the Jacobians are empty).

        Raises:
            CalibrationError: a play effect is on but the inputs carry no play operator, or a
                heating or relaxation effect is on but they carry no command history.

        """
        names = self.global_names
        jac_g: dict[str, FloatArray] = {}
        T = data.temperature
        Ta = T + self._value(local, g, self.lead) * data.temperature_rate if self.lead else T
        # d T_a / d parameter of the effects that move T_a, for their Jacobian columns
        dTa: dict[str, FloatArray] = {}
        if self.lead:
            dTa[self.key(self.lead)] = data.temperature_rate
        if self.heating:
            gain_h = self._value(local, g, self.heating, 0)
            excess, d_excess, d_shape = self._lowpass(
                data, self.heating, self._global(g, self.heating, 1), g
            )
            Ta = Ta + gain_h * excess
            dTa[self.key(self.heating, 0)] = excess
            dTa[self.key(self.heating, 1)] = gain_h * d_excess
            for i, column in enumerate(d_shape):
                dTa[self.key(self.heating, 2 + i)] = gain_h * column

        V = data.voltage
        dV: dict[str, FloatArray] = {}  # d V_eff / d parameter
        dV_dTa: FloatArray | None = None
        if self.play:
            if data.play is None:
                raise CalibrationError(f"{self.play.name} needs the play operator in the inputs")
            # the last play parameter is the weights' temperature slope beta [1/degC]
            beta = self._global(g, self.play, self.operators)
            dT = Ta - data.mean_temperature
            a_T = np.exp(-beta * dT)
            gaps = data.play - V  # (K, A, n)
            mix = sum(self._global(g, self.play, i) * gaps[i] for i in range(self.operators))
            V = V + a_T * mix
            for i in range(self.operators):
                dV[self.key(self.play, i)] = a_T * gaps[i]
            dV[self.key(self.play, self.operators)] = -dT * a_T * mix
            dV_dTa = -beta * a_T * mix
        if self.relaxation:
            r = self._global(g, self.relaxation, 0)
            log_fc = self._global(g, self.relaxation, 1)
            # tau = 1 / (2 pi f_c): d / d(log f_c) = -d / d(log tau)
            state, d_state, _ = self._lowpass(
                data, self.relaxation, -log_fc - np.log(2.0 * np.pi), g
            )
            high = data.voltage - state
            V = V - r * high
            dV[self.key(self.relaxation, 0)] = -high
            dV[self.key(self.relaxation, 1)] = -r * d_state

        Ts = Ta - self.Tm
        curved = self.law is not None
        n_law = len(LINEAR_LAW) + (len(self.law.local_parameters) if self.law else 0)
        A, n = np.shape(Ts)
        jac_l = np.empty((A, n, n_law + len(self.per_actuator)) if jacobian else (A, n, 0))
        known = _last_tanh.get(self, data, local, g)
        if default_backend() is Backend.FUSED:
            from es_calibration.model.law_loop import fused_law

            H, dH_dV, dH_dT, th = fused_law(
                Ts, V, local, curved=curved, length=self.L, jacobian=jacobian,
                with_temperature=bool(dTa), voltage_by_temperature=dV_dTa, columns=jac_l,
                th=known,
            )
        else:
            H, dH_dV, dH_dT, th = self._law(Ts, V, local, jacobian, dTa, dV_dTa, jac_l, known)
        if known is None:
            _last_tanh.put(self, data, local, g, th)
        scale: FloatArray | float = 1.0  # d(prediction)/dH
        if jacobian:
            for key, column in dV.items():
                jac_g[key] = dH_dV * column
        F = H
        if self.gain:
            frac = self._global(g, self.gain, 0)
            d_tau = float(np.exp(self._global(g, self.gain, 1)))
            # nu beyond [1/5, 5] makes a step or a flat line, not an aging law
            log_nu = self._global(g, self.gain, 2)
            nu = float(np.exp(np.clip(log_nu, -DRIFT_LOG_NU_LIMIT, DRIFT_LOG_NU_LIMIT)))
            ratio = np.maximum(data.t, 0.0) / d_tau
            s = np.minimum(ratio, 1e6) ** nu
            e = np.exp(-s)
            gain = 1.0 - frac * (1.0 - e)
            log_ratio = np.log(np.where(ratio > 0.0, ratio, 1.0))
            F = H * gain
            if jacobian:
                jac_g[self.key(self.gain, 0)] = -(1.0 - e) * H
                jac_g[self.key(self.gain, 1)] = frac * e * nu * s * H
                jac_g[self.key(self.gain, 2)] = -frac * e * s * log_ratio * nu * H
                for key in dV:
                    jac_g[key] = jac_g[key] * gain
            scale = gain
        # d F / d T_a, for the sensor lag and the heating (before the coupling spreads them)
        if jacobian:
            for key, column in dTa.items():
                jac_g[key] = scale * dH_dT * column
        Z = F
        if self.spatial:
            c = self._global(g, self.spatial)
            lap_F = neighbour_laplacian(F, data.grid)
            Z = F + c * lap_F
            own = 1.0 - c * neighbour_count(data.grid)
            # shared parameters move every actuator: (I + c lap) of their columns is exact;
            # per-actuator ones keep their own actuator's term (as the law's coefficients)
            for key, column in jac_g.items():
                jac_g[key] = (
                    column * own
                    if key in self.per_actuator
                    else column + c * neighbour_laplacian(column, data.grid)
                )
            jac_g[self.key(self.spatial)] = lap_F
            scale = scale * own
        Ta_rel = Ta - data.mean_temperature
        for effect in self.additive:
            values = {p: self._global(g, effect, i) for i, p in enumerate(effect.fit_names())}
            term = effect.additive(values, data.t, Ta_rel)
            Z = Z + term.value
            for i, column in enumerate(term.columns):
                jac_g[self.key(effect, i)] = column
            if jacobian:
                for key, column in dTa.items():
                    jac_g[key] = jac_g[key] + term.d_temperature * column
        if not jacobian:
            return Evaluation(np.asarray(Z, np.float64), jac_l, np.zeros((A, n, 0)))
        if not isinstance(scale, float):
            jac_l[..., :n_law] *= np.asarray(scale)[..., None]
        for i, key in enumerate(self.per_actuator, n_law):
            jac_l[..., i] = jac_g[key]
        jac_glob = np.empty((A, n, len(names)))
        for i, name in enumerate(names):
            jac_glob[..., i] = jac_g[name]
        return Evaluation(np.asarray(Z, np.float64), jac_l, jac_glob)


def play_operator(
    command: FloatArray,
    threshold: float | FloatArray,
    keep: IndexArray,
    state: FloatArray | None = None,
) -> FloatArray:
    """Return the backlash (play) operator of a command sequence at the rows ``keep``.

    ``command`` is (N, A), time-major; ``threshold`` a scalar or an array broadcasting against
    (A,) (a stack of thresholds works with ``command`` (N, 1)). The state starts at the clipped
    zero, y_0 = clip(0, V_0 - r, V_0 + r), or continues from ``state`` (the operator's value
    after the previous rows, a streamed command). Only the rows ``keep`` (sorted) are returned, so a
    long run needs no full-size output. The loop is over time: compiled where the kernels are
    fused (:mod:`es_calibration.model.play_loop`, the same numbers), else in numpy,
    vectorised over actuators.
    """
    r = np.asarray(threshold, np.float64)
    shape = np.broadcast_shapes(command.shape[1:], r.shape)
    start = np.zeros(shape) if state is None else np.array(np.broadcast_to(state, shape))
    state = np.clip(start, command[0] - r, command[0] + r)
    out = np.empty((len(keep), *shape))
    if not len(keep):
        return out
    if default_backend() is Backend.FUSED:
        from es_calibration.model.play_loop import play_rows

        size = int(np.prod(shape, dtype=np.intp))
        own = command.shape[1:]
        columns = np.broadcast_to(np.arange(int(np.prod(own, dtype=np.intp))).reshape(own), shape)
        play_rows(np.ascontiguousarray(command.reshape(command.shape[0], -1), np.float64),
                  np.ascontiguousarray(columns.reshape(size), np.intp),
                  np.ascontiguousarray(np.broadcast_to(r, shape).reshape(size)),
                  np.ascontiguousarray(state.reshape(size)), np.ascontiguousarray(keep, np.intp),
                  out.reshape(len(keep), size))
        return out
    low = np.empty(shape)
    # which output slot each needed row fills (rows may repeat)
    last = int(keep[-1])
    first_slot = np.searchsorted(keep, np.arange(last + 1), side="left")
    end_slot = np.searchsorted(keep, np.arange(last + 1), side="right")
    maximum, minimum, subtract, add = np.maximum, np.minimum, np.subtract, np.add
    for i in range(last + 1):
        row = command[i]
        subtract(row, r, out=low)
        maximum(state, low, out=state)
        add(row, r, out=low)
        minimum(state, low, out=state)
        if end_slot[i] > first_slot[i]:
            out[first_slot[i] : end_slot[i]] = state
    return out
