"""Calibration files: the ``ros__parameters`` YAML the node and ``margcal calibrate`` write and read."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from .calibration import Calibration
from .errors import CalibrationFileError

__all__ = ["calibration_from_yaml", "calibration_to_yaml", "load_calibrations", "save_calibrations"]

Array = NDArray[np.float64]


def _dump(cals: dict[str, Calibration], node: str) -> str:
    doc = {node: {"ros__parameters": {"calibration": {k: c.to_dict() for k, c in cals.items()}}}}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def _parse(text: str, where: str) -> dict[str, Calibration]:
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        msg = f"{where} is not valid YAML ({exc}); delete it or restore a backup"
        raise CalibrationFileError(msg) from exc
    if not isinstance(doc, dict):
        msg = f"{where} is not a ros__parameters calibration file"
        raise CalibrationFileError(msg)
    for node_params in doc.values():
        if isinstance(node_params, dict) and isinstance(node_params.get("ros__parameters"), dict):
            block = node_params["ros__parameters"].get("calibration")
            if isinstance(block, dict) and block:
                return {str(k): Calibration.from_dict(v) for k, v in block.items()}
    msg = f"{where} has no '<node>: ros__parameters: calibration:' block"
    raise CalibrationFileError(msg)


def save_calibrations(path: str | os.PathLike[str], cals: dict[str, Calibration], node: str = "margcal") -> Path:
    """Write calibrations per sensor atomically (temp file in the same folder, fsync, rename)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    text = _dump(cals, node)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; a params file must be readable like any other
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return target


def load_calibrations(path: str | os.PathLike[str]) -> dict[str, Calibration]:
    """Read the calibrations of a file written by ``save_calibrations``; CalibrationFileError if unusable."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"cannot read calibration file {p}: {exc}"
        raise CalibrationFileError(msg) from exc
    return _parse(text, str(p))


def calibration_to_yaml(cal: Calibration, node: str = "margcal") -> str:
    """One calibration alone as a ``ros__parameters`` YAML document."""
    return _dump({cal.sensor or "sensor": cal}, node)


def calibration_from_yaml(text: str, sensor: str | None = None) -> Calibration:
    """Read one calibration from YAML text (the only one, or the one named ``sensor``)."""
    cals = _parse(text, "<text>")
    if sensor is None:
        if len(cals) != 1:
            msg = f"YAML holds calibrations for {sorted(cals)}; name the sensor to read"
            raise CalibrationFileError(msg)
        return next(iter(cals.values()))
    if sensor not in cals:
        msg = f"YAML holds no calibration for sensor {sensor!r} (has {sorted(cals)})"
        raise CalibrationFileError(msg)
    return cals[sensor]
