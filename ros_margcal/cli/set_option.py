"""``--set KEY=VALUE``: any option of the streaming calibrator (``stream.config.PipelineConfig``) from the command line.

``replay`` and ``calibrate`` take it, repeatable, so that every option a message asks to raise
(``max_magnitude``, ``gate_cv_threshold``, ``max_iter``, ``max_offset_ratio``, ...) can be raised. A key may
carry its sensor (``accel.gate_cv_threshold``, as the messages name it); without one it applies to every
sensor. The value is parsed by the field's kind in ``FIELD_SPECS`` (a number, an integer, true/false, a
string; ``none`` where the field admits None, ``inf`` where it admits +inf) and checked against its range.
An unknown key or a bad value is a ``ConfigError`` (exit 2) naming it.
"""

from __future__ import annotations

import difflib
import math
from typing import Any

from ..model.errors import ConfigError
from ..stream.config import FIELD_SPECS, FieldSpec

__all__ = ["SET_HELP", "parse_sets", "sensor_options"]

SET_HELP = ("set an option of the streaming calibrator, e.g. --set max_offset_ratio=20 or --set "
            "accel.gate_cv_threshold=0.01 (repeatable; any field of stream/config.py PipelineConfig; "
            "SENSOR.KEY applies to that sensor only)")
_TRUE, _FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")
_FIXED = ("sensor", "unit")  # given by --sensor and --unit, never by --set


def _value(key: str, spec: FieldSpec, text: str) -> Any:
    """``text`` as the kind of field ``key`` (module docstring), checked by the spec."""
    low = text.strip().lower()
    if spec.none_ok and low in ("none", "null"):
        value: Any = None
    elif spec.kind is bool:
        if low not in _TRUE + _FALSE:
            raise ConfigError(f"--set {key}={text!r}: {key} takes true or false")
        value = low in _TRUE
    elif spec.kind is int:
        try:
            value = int(low)
        except ValueError:
            raise ConfigError(f"--set {key}={text!r}: {key} takes an integer") from None
    elif spec.kind is float:
        try:
            value = float(low)
        except ValueError:
            raise ConfigError(f"--set {key}={text!r}: {key} takes a number") from None
        if math.isinf(value) and not spec.inf_ok:
            raise ConfigError(f"--set {key}={text!r}: {key} must be finite")
    else:
        value = text
    spec.check(key, value)
    return value


def parse_sets(items: list[str] | None) -> dict[str, dict[str, Any]]:
    """``--set`` items as ``{"": options for every sensor, "mag": ..., "accel": ...}``; ConfigError on a bad one."""
    out: dict[str, dict[str, Any]] = {"": {}, "mag": {}, "accel": {}}
    for item in items or ():
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE, e.g. --set max_offset_ratio=20")
        sensor, dot, name = key.rpartition(".")
        if dot and sensor not in ("mag", "accel"):
            raise ConfigError(f"--set {item!r}: the prefix of {key!r} must be mag. or accel., got {sensor!r}")
        if name in _FIXED:
            raise ConfigError(f"--set {name}: give it with --{name}")
        spec = FIELD_SPECS.get(name)
        if spec is None:
            near = difflib.get_close_matches(name, list(FIELD_SPECS), n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else "; the options are the fields of PipelineConfig"
            raise ConfigError(f"--set {item!r}: unknown option {name!r}{hint}")
        out[sensor][name] = _value(key, spec, text)
    return out


def sensor_options(sets: dict[str, dict[str, Any]], sensor: str) -> dict[str, Any]:
    """The options for ``sensor``: those for every sensor, then its own."""
    return {**sets.get("", {}), **sets.get(sensor, {})}
