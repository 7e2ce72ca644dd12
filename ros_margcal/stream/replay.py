"""Replay: a recording through the streaming calibrators in message order, as the node would run them.

Every Imu / MagneticField message of a bag (or every row of a CSV) goes to the ``SensorCalibrator``
of its sensor with the message stamp as time (a MagneticField message with the angular rate of the
latest Imu message, as the node pairs them: ``config.GYRO_PAIR_S``; a CSV row with its ``gx,gy,gz``);
``replay`` returns the calibrators, the timeline of events and periodic statuses, and the message
count. ``margcal replay`` prints it.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from ..model.errors import RecordingError
from ..recordings.bag import iter_bag_messages
from ..recordings.read import read_recording
from .calibrator import SensorCalibrator
from .config import GYRO_PAIR_S, PipelineConfig
from .status import Event, EventKind

__all__ = ["replay"]

_SENSOR_OF_KIND = {"imu": "accel", "mag": "mag"}
_UNIT_OF_SENSOR = {"accel": "m/s^2", "mag": "T"}


def _samples(path: Path, sensor: str | None, unit: str | None) -> tuple[Iterator[tuple[float, str, Any, Any]], dict[str, str]]:
    """(t, sensor, xyz, gyro) in recording order, and the raw unit of each sensor."""

    if path.suffix.lower() == ".csv":
        rec = read_recording(path, sensor=sensor)
        s = sensor or rec.sensor or "mag"
        gyro = rec.gyro if rec.gyro is not None else [None] * len(rec)
        it = ((float(t), s, v, g) for t, v, g in zip(rec.t, rec.raw, gyro, strict=True))
        return it, {s: unit or rec.unit or _UNIT_OF_SENSOR[s]}
    return _paired(iter_bag_messages(path)), dict(_UNIT_OF_SENSOR)


def _paired(messages: Iterator[Any]) -> Iterator[tuple[float, str, Any, Any]]:
    """Bag messages as (t, sensor, xyz, gyro), a MagneticField one with the latest Imu rate (``GYRO_PAIR_S``)."""
    rate: tuple[float, str, Any] | None = None
    for m in messages:
        frame = str(getattr(getattr(m.msg, "header", None), "frame_id", ""))
        if m.kind == "imu":
            rate = None if m.gyro is None else (m.t, frame, m.gyro)
            yield m.t, "accel", m.xyz, m.gyro
        else:
            ok = rate is not None and abs(m.t - rate[0]) <= GYRO_PAIR_S and rate[1] == frame
            yield m.t, "mag", m.xyz, rate[2] if ok and rate is not None else None


def replay(path: Path, *, sensor: str | None = None, unit: str | None = None, status_every: float = 10.0,
           progress: bool = True, on_line: Any = None, validator: Any = None,
           options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run the pipeline over a recording; returns calibrators, timeline and counts.

    Args:
        path: the recording.
        sensor, unit: for a CSV (see the command's options).
        status_every: seconds of recording time between timeline status entries (0: events only).
        progress: show a progress bar on stderr (tqdm); timeline lines and log records (the root
            logger's console handlers) are written above it, never into it.
        on_line: called with each timeline line (str) as it happens.
        validator: the validator every calibrator uses (None: the shipped default).
        options: ``PipelineConfig`` options for every calibrator (e.g. ``{"partial_fit": False}``).

    Raises:
        RecordingError: the recording cannot be read, or holds no sensor message at all.
    """
    samples, units = _samples(path, sensor, unit)
    cals: dict[str, SensorCalibrator] = {}
    timeline: list[dict[str, Any]] = []
    next_status: dict[str, float] = {}
    n = 0
    # disable=None: no bar when stderr is not a terminal (a log file, a pipe)
    with tqdm(samples, desc="replay", unit=" msg", file=sys.stderr, disable=None if progress else True) as bar, \
            logging_redirect_tqdm(tqdm_class=tqdm):

        def emit(line: str) -> None:
            with tqdm.external_write_mode(file=sys.stdout):  # clears the bar, writes, redraws it
                on_line(line)
                sys.stdout.flush()

        for t, s, xyz, gyro in bar:
            cal = cals.get(s)
            if cal is None:
                cfg = PipelineConfig.for_sensor(s, units.get(s), **(options or {}))
                cal = cals[s] = SensorCalibrator(s, cfg, validator=validator)
                next_status[s] = t
            for ev in cal.push(t, xyz, gyro):
                timeline.append(_event_entry(ev))
                if on_line:
                    emit(f"{ev.t:9.2f} s  {s:5s}  {ev.kind.value:10s} {ev.message}")
            if status_every > 0 and t >= next_status[s]:
                st = cal.status(t)
                timeline.append({"kind": "status", **st.to_dict()})
                next_status[s] = t + status_every
                if on_line:
                    emit(f"{t:9.2f} s  {s:5s}  {'status':10s} [{st.level.name}] {st.message}")
            n += 1
            if n % 1000 == 0:
                bar.set_postfix_str(f"t = {t:.1f} s", refresh=False)
    if n == 0:  # as the offline readers do: an empty recording is an error, not "final state after 0 messages"
        msg = f"{path} holds no sensor_msgs/Imu or MagneticField messages (or CSV rows) to replay"
        raise RecordingError(msg)
    return {"calibrators": cals, "timeline": timeline, "messages": n}


def _event_entry(ev: Event) -> dict[str, Any]:
    out: dict[str, Any] = {"kind": ev.kind.value, "t": ev.t, "sensor": ev.sensor, "message": ev.message}
    if ev.kind is EventKind.CALIBRATED and ev.calibration is not None:
        out["calibration"] = ev.calibration.to_dict()
    return out
