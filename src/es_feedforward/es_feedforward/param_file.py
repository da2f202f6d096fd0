"""Feedforward configuration <-> ROS parameters and ROS 2 parameters YAML files.

One flat set of parameter names (``docs/architecture.md``, README of es_feedforward):
``rows``, ``cols``, ``mode``, ``v_limit``, ``reference_temperature``, ``temperature_timeout``,
``law.<field>`` (double arrays, length 1 or rows*cols, row-major), ``compensation.<name>``
and ``observer.<kp|ki|iterations|tolerance>``. The calibration tool writes files with
:func:`write_params_file`; the node is started with ``--ros-args --params-file FILE`` and
checks every set with :func:`config_from_parameters`, the same code path as
:func:`read_params_file`. Files are written with :func:`es_node_runtime.param_yaml.dump_parameters`
(every float with a dot, so ``ros2 param load`` reads it as a float too), and a dot-less
exponent such as ``-4e-17`` (a string to YAML 1.1, as ``ros2 param dump`` may write it) is
read as the float it stands for.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields, replace
from pathlib import Path
from typing import Final

import numpy as np
import yaml

from es_feedforward.compensation import PREFIX as COMPENSATION_PREFIX
from es_feedforward.compensation import RANGES as COMPENSATION_RANGES
from es_feedforward.errors import ParameterError, ParamsFileError
from es_feedforward.feedforward import FeedforwardConfig, Mode, ObserverGains
from es_node_runtime.param_spec import ParameterValues
from es_node_runtime.param_yaml import dump_parameters, floats_from_strings
from es_physics.params import ActuatorParams

LAW_PREFIX: Final = "law."
OBSERVER_PREFIX: Final = "observer."
#: Node name the calibration tool writes files for.
DEFAULT_NODE_NAME: Final = "feedforward"
#: Name of the file the calibration tool writes into its output directory.
CALIBRATION_FILE_NAME: Final = "feedforward_params.yaml"
LAW_FIELDS: Final = tuple(f.name for f in fields(ActuatorParams))
#: The calibration's verdict on the file (informational node parameters, read-only).
CALIBRATION_VERDICT: Final = "calibration.verdict"
CALIBRATION_REASONS: Final = "calibration.reasons"
#: The verdicts a calibration gives ("": no calibration said anything).
VERDICTS: Final = ("", "trusted", "provisional", "unusable")
OBSERVER_FIELDS: Final = tuple(f.name for f in fields(ObserverGains))


def _law_array(name: str, value: object, shape: tuple[int, int]) -> float | np.ndarray:
    """Return a law parameter as a scalar (length 1) or a (rows, cols) map (length rows*cols)."""
    values = np.atleast_1d(np.asarray(value, dtype=np.float64)).ravel()
    if values.size == 1:
        return float(values[0])
    if values.size != shape[0] * shape[1]:
        raise ParameterError(
            f"{LAW_PREFIX}{name} has {values.size} values, expected 1 or rows*cols = "
            f"{shape[0] * shape[1]}"
        )
    return values.reshape(shape)


def config_from_parameters(
    values: Mapping[str, object], base: FeedforwardConfig | None = None
) -> FeedforwardConfig:
    """Return the configuration described by flat parameter ``values`` on top of ``base``.

    Names not given keep the value of ``base`` (defaults when ``base`` is ``None``; then
    ``rows`` and ``cols`` are required). Unknown names are ignored (other node parameters).

    Raises:
        es_feedforward.errors.ParameterError: a value has the wrong type, size or range (a
            ``ValueError``); the message gives the reason.

    """
    try:
        return _config_from_parameters(values, base)
    except (TypeError, ValueError) as err:
        raise ParameterError(str(err)) from None


def _config_from_parameters(
    values: Mapping[str, object], base: FeedforwardConfig | None
) -> FeedforwardConfig:
    typed = ParameterValues(values)
    if base is None:
        if "rows" not in values or "cols" not in values:
            raise ParameterError("rows and cols are required")
        base = FeedforwardConfig(shape=(1, 1))
    rows = typed.get_int("rows", base.shape[0])
    cols = typed.get_int("cols", base.shape[1])
    shape = (rows, cols)
    if rows < 1 or cols < 1:
        raise ParameterError(f"rows and cols must be >= 1, got {rows} x {cols}")
    mode_name = str(values.get("mode", base.mode.value))
    if mode_name not in Mode.__members__.values():
        raise ParameterError(f"mode={mode_name!r} is not one of {[m.value for m in Mode]}")
    law = {
        name: _law_array(name, values[LAW_PREFIX + name], shape)
        for name in LAW_FIELDS
        if LAW_PREFIX + name in values
    }
    compensation = {
        name: typed.get_float(COMPENSATION_PREFIX + name)
        for name in COMPENSATION_RANGES
        if COMPENSATION_PREFIX + name in values
    }
    gains = base.observer
    observer = ObserverGains(
        kp=typed.get_float(OBSERVER_PREFIX + "kp", gains.kp),
        ki=typed.get_float(OBSERVER_PREFIX + "ki", gains.ki),
        iterations=typed.get_int(OBSERVER_PREFIX + "iterations", gains.iterations),
        tolerance=typed.get_float(OBSERVER_PREFIX + "tolerance", gains.tolerance),
    )
    config = FeedforwardConfig(
        shape=shape,
        params=replace(base.params, **law),
        mode=Mode(mode_name),
        v_limit=typed.get_float("v_limit", base.v_limit),
        reference_temperature=typed.get_float(
            "reference_temperature", base.reference_temperature
        ),
        temperature_timeout=typed.get_float("temperature_timeout", base.temperature_timeout),
        compensation=base.compensation.replaced(compensation),
        observer=observer,
    )
    reason = config.reason_to_reject()
    if reason is not None:
        raise ParameterError(reason)
    return config


def config_to_parameters(config: FeedforwardConfig) -> dict[str, object]:
    """Return the flat parameter values of ``config`` (law maps as row-major lists)."""
    out: dict[str, object] = {
        "rows": config.shape[0],
        "cols": config.shape[1],
        "mode": config.mode.value,
        "v_limit": float(config.v_limit),
        "reference_temperature": float(config.reference_temperature),
        "temperature_timeout": float(config.temperature_timeout),
    }
    for name in LAW_FIELDS:
        value = np.asarray(getattr(config.params, name), np.float64)
        if value.ndim:
            value = np.broadcast_to(value, config.shape)
        out[LAW_PREFIX + name] = [float(v) for v in value.ravel()]
    for name, number in config.compensation.values().items():
        out[COMPENSATION_PREFIX + name] = number
    for name in OBSERVER_FIELDS:
        out[OBSERVER_PREFIX + name] = getattr(config.observer, name)
    return out


def write_params_file(
    path: str | Path,
    config: FeedforwardConfig,
    node_name: str = DEFAULT_NODE_NAME,
    verdict: tuple[str, list[str]] | None = None,
) -> None:
    """Write ``config`` as a ROS 2 parameters YAML for the node ``node_name``.

    ``verdict`` (level, reasons) is written as ``calibration.verdict`` and
    ``calibration.reasons`` (a calibration's judgement of the file; None: not written).
    """
    parameters = config_to_parameters(config)
    if verdict is not None:
        parameters[CALIBRATION_VERDICT] = verdict[0]
        parameters[CALIBRATION_REASONS] = list(verdict[1]) or [""]
    document = {node_name: {"ros__parameters": parameters}}
    Path(path).write_text(dump_parameters(document), encoding="utf-8")


def _flatten(tree: Mapping[str, object], prefix: str = "") -> dict[str, object]:
    """Flatten nested parameter dicts (``law: {L: ...}``) into dotted names (``law.L``)."""
    flat: dict[str, object] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def read_params_verdict(
    path: str | Path, node_name: str = DEFAULT_NODE_NAME
) -> tuple[str, list[str]]:
    """Return the file's calibration verdict and reasons (("", []) when it has none).

    Raises:
        es_feedforward.errors.ParamsFileError: as :func:`read_params_file`, or a verdict not
            in :data:`VERDICTS`.

    """
    values = _node_values(path, node_name)
    level = str(values.get(CALIBRATION_VERDICT, ""))
    if level not in VERDICTS:
        raise ParamsFileError(f"{path}: {CALIBRATION_VERDICT} {level!r} is not one of "
                              f"{', '.join(v for v in VERDICTS if v)}")
    reasons = values.get(CALIBRATION_REASONS, [])
    reasons = [str(r) for r in reasons if str(r)] if isinstance(reasons, list) else [str(reasons)]
    return level, reasons


def read_params_file(path: str | Path, node_name: str = DEFAULT_NODE_NAME) -> FeedforwardConfig:
    """Read the feedforward configuration from a ROS 2 parameters YAML.

    Takes the parameters of ``node_name`` (with or without a leading ``/``) and of ``/**``
    (wildcard), the node's own entries winning, as ROS does. Dot-less exponent strings
    (``-4e-17``) are read as floats (:func:`es_node_runtime.param_yaml.floats_from_strings`).

    Raises:
        es_feedforward.errors.ParamsFileError: unreadable file, no parameters for the node,
            or an invalid value (a ``ValueError``; one readable line).

    """
    values = _node_values(path, node_name)
    try:
        return config_from_parameters(values)
    except ValueError as err:
        raise ParamsFileError(f"{path}: {err}") from None


def _node_values(path: str | Path, node_name: str) -> dict[str, object]:
    """Return the flat parameters of ``node_name`` (and ``/**``) in the file at ``path``.

    Raises:
        es_feedforward.errors.ParamsFileError: unreadable file or no parameters for the node.

    """
    try:
        document, _ = floats_from_strings(yaml.safe_load(Path(path).read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise ParamsFileError(
            f"cannot read parameters file {path}: {err}".splitlines()[0]
        ) from None
    if not isinstance(document, Mapping):
        raise ParamsFileError(f"{path}: not a ROS 2 parameters file (no node mapping)")
    values: dict[str, object] = {}
    found = False
    for key in ("/**", node_name.lstrip("/"), "/" + node_name.lstrip("/")):
        section = document.get(key)
        if isinstance(section, Mapping) and isinstance(section.get("ros__parameters"), Mapping):
            values.update(_flatten(section["ros__parameters"]))
            found = True
    if not found:
        raise ParamsFileError(f"{path}: no ros__parameters for node {node_name!r} or '/**'")
    return values
