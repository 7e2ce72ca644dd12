"""Replay: a recording through the streaming calibrators in message order, as the node would run them.

Every Imu / MagneticField message of a bag (or every row of a CSV) goes to the ``SensorCalibrator``
of its topic with the message stamp as time (a MagneticField message with the angular rate of the
latest Imu message of its frame, as the node pairs them: ``config.GYRO_PAIR_S``; a CSV row with its
``gx,gy,gz``); ``replay`` returns the calibrators, the timeline of events and periodic statuses, and
the message count. ``margcal replay`` prints it.

One calibrator per sensor topic: a bag with one Imu and one MagneticField topic gives the calibrators
``accel`` and ``mag``; a sensor with several topics (two magnetometers) gives one calibrator per topic,
named ``mag:/left/mag``, never one fitted to the pooled readings of different sensors. ``topics``
restricts a bag to some of its topics, ``sensor`` to one sensor.

A CSV is read in file order with its stamps as they are: a clock that goes back (a logger restart) is
the calibrator's new time base (``intake``), as for a bag.

Units: MagneticField is tesla and Imu m/s² (REP-145); ``unit`` overrides the unit of one sensor (the
``sensor``, the only sensor of the recording, or the one ``unit`` is a unit of: gauss is a
magnetometer's, g an accelerometer's) for a driver that publishes another unit.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from ..model.errors import RecordingError
from ..recordings.bag import bag_topics, is_bag, iter_bag_messages
from ..recordings.read import read_recording
from .calibrator import SensorCalibrator
from .config import GYRO_PAIR_S, PipelineConfig
from .status import Event, EventKind
from .units import unit_scale

__all__ = ["replay", "replay_plan"]

_IMU, _MAG = "sensor_msgs/msg/Imu", "sensor_msgs/msg/MagneticField"
_SENSOR_OF_TYPE = {_IMU: "accel", _MAG: "mag"}
_UNIT_OF_SENSOR = {"accel": "m/s^2", "mag": "T"}

Sample = tuple[float, str, str, Any, Any]
"""(t, calibrator name, sensor, xyz, gyro)."""


def _unit_sensor(unit: str, sensors: set[str], where: str) -> str:
    """The sensor of ``sensors`` that ``unit`` belongs to (the only one, or the one whose unit it is)."""
    if len(sensors) == 1:
        return next(iter(sensors))
    owners = {s for s in sorted(sensors) if unit_scale(s, unit) is not None}
    if len(owners) == 1:
        return owners.pop()
    msg = (f"--unit {unit!r} for {where}, which has Imu and MagneticField topics: say which sensor reads in "
           f"{unit!r} with --sensor mag or --sensor accel")
    raise RecordingError(msg)


def replay_plan(path: Path, *, sensor: str | None = None, unit: str | None = None,
                topics: Iterable[str] | None = None) -> dict[str, tuple[str, str, str]]:
    """What ``replay`` will run: calibrator name -> (sensor, raw unit, topic; "" for a CSV).

    Raises:
        RecordingError: a topic a bag does not have (the message lists its sensor topics), a ``topics`` or
            ``sensor`` that leaves nothing, ``topics`` for a CSV, a ``unit`` whose sensor is ambiguous.
    """
    wanted = None if topics is None else list(dict.fromkeys(topics))
    if not is_bag(path):
        if wanted:
            msg = f"--topic applies to rosbag2 recordings, not to {path}"
            raise RecordingError(msg)
        return {}
    have = {t: _SENSOR_OF_TYPE[m] for t, m in sorted(bag_topics(path).items()) if m in _SENSOR_OF_TYPE}
    listing = ", ".join(f"{t} ({'Imu' if s == 'accel' else 'MagneticField'})" for t, s in have.items()) or "none"
    if wanted:
        missing = [t for t in wanted if t not in have]
        if missing:
            msg = f"{path} has no Imu or MagneticField topic {', '.join(missing)}; its sensor topics: {listing}"
            raise RecordingError(msg)
        chosen = {t: have[t] for t in wanted}
    else:
        chosen = dict(have)
    if sensor is not None:
        other = [t for t, s in chosen.items() if s != sensor] if wanted else []
        if other:
            msg = f"{path}: topic {', '.join(other)} is not a {sensor!r} sensor; its sensor topics: {listing}"
            raise RecordingError(msg)
        chosen = {t: s for t, s in chosen.items() if s == sensor}
    if not chosen:
        what = {"accel": "Imu", "mag": "MagneticField"}.get(sensor or "", "Imu or MagneticField")
        msg = f"{path} has no {what} topic to replay; its sensor topics: {listing}"
        raise RecordingError(msg)
    sensors = set(chosen.values())
    units = dict(_UNIT_OF_SENSOR)
    if unit:
        units[sensor if sensor is not None else _unit_sensor(unit, sensors, str(path))] = unit
    per = {s: [t for t, ts in chosen.items() if ts == s] for s in sensors}
    return {(s if len(per[s]) == 1 else f"{s}:{t}"): (s, units[s], t) for t, s in chosen.items()}


def _samples(path: Path, sensor: str | None, unit: str | None,
             plan: dict[str, tuple[str, str, str]]) -> tuple[Iterator[Sample], dict[str, tuple[str, str, str]]]:
    """(t, name, sensor, xyz, gyro) in recording order, and the plan with the CSV's calibrator filled in."""

    if not plan:
        rec = read_recording(path, sensor=sensor, order="file")  # the calibrator judges the stamps (a restart)
        s = sensor or rec.sensor or "mag"
        # rows as Python floats: the intake's fast path (a numpy row costs it a few us more a sample)
        gyro = rec.gyro.tolist() if rec.gyro is not None else [None] * len(rec)
        it = ((t, s, s, v, g) for t, v, g in zip(rec.t.tolist(), rec.raw.tolist(), gyro, strict=True))
        return it, {s: (s, unit or rec.unit or _UNIT_OF_SENSOR[s], "")}
    names = {topic: name for name, (_, _, topic) in plan.items()}
    return _paired(iter_bag_messages(path, topics=set(names)), names), plan


def _paired(messages: Iterator[Any], names: dict[str, str]) -> Iterator[Sample]:
    """Bag messages as (t, name, sensor, xyz, gyro), a MagneticField one with the latest Imu rate of its frame
    (``GYRO_PAIR_S``)."""
    rates: dict[str, tuple[float, Any]] = {}  # frame_id -> (t, gyro) of the latest Imu with a gyro
    for m in messages:
        frame = str(getattr(getattr(m.msg, "header", None), "frame_id", ""))
        name = names[m.topic]
        if m.kind == "imu":
            if m.gyro is None:
                rates.pop(frame, None)
            else:
                rates[frame] = (m.t, m.gyro)
            yield m.t, name, "accel", m.xyz, m.gyro
        else:
            rate = rates.get(frame)
            ok = rate is not None and abs(m.t - rate[0]) <= GYRO_PAIR_S
            yield m.t, name, "mag", m.xyz, rate[1] if ok and rate is not None else None


def replay(path: Path, *, sensor: str | None = None, unit: str | None = None, status_every: float = 10.0,
           progress: bool = True, on_line: Any = None, validator: Any = None,
           topics: Iterable[str] | None = None, sensor_options: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """Run the pipeline over a recording; returns calibrators, timeline, counts and the topic of each calibrator.

    Args:
        path: the recording.
        sensor: a CSV's sensor (default: from the name); a bag's sensor to replay (default: both).
        unit: the raw unit of a CSV, or of one sensor of a bag (module docstring; default tesla, m/s²).
        status_every: seconds of recording time between timeline status entries (0: events only).
        progress: show a progress bar on stderr (tqdm); timeline lines and log records (the root
            logger's console handlers) are written above it, never into it.
        on_line: called with each timeline line (str) as it happens.
        validator: the validator every calibrator uses (None: the shipped default).
        topics: a bag's topics to replay (default: every Imu and MagneticField topic).
        sensor_options: ``PipelineConfig`` options per sensor (``mag``, ``accel``) for that sensor's calibrators (e.g.
            ``{"mag": {"partial_fit": False}}``).

    Returns:
        ``calibrators`` (name -> SensorCalibrator: ``mag``, ``accel``, or ``mag:<topic>`` when a sensor has
        several topics), ``topics`` (name -> topic, "" for a CSV), ``timeline`` and ``messages``.

    Raises:
        RecordingError: the recording cannot be read, holds no sensor message at all, or lacks a topic
            asked for (``replay_plan``).
    """
    samples, plan = _samples(path, sensor, unit, replay_plan(path, sensor=sensor, unit=unit, topics=topics))
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

        for t, name, s, xyz, gyro in bar:
            cal = cals.get(name)
            if cal is None:
                cfg = PipelineConfig.for_sensor(s, plan[name][1], **(sensor_options or {}).get(s, {}))
                cal = cals[name] = SensorCalibrator(s, cfg, validator=validator)
                next_status[name] = -math.inf
            for ev in cal.push(t, xyz, gyro):
                timeline.append(_event_entry(ev, name))
                if on_line:
                    emit(f"{ev.t:9.2f} s  {name:5s}  {ev.kind.value:10s} {ev.message}")
            # the cadence runs on the calibrator's clock, not the message's stamp: one far-future or jumped stamp
            # (dropped) printed a status at 1e18 s, then none for as long as the jump; stamps that restart
            # (a new time base) restart it
            now, due = cal.clock, next_status[name]
            if status_every > 0 and (now >= due or now < due - status_every):
                st = cal.status(now)
                timeline.append({"kind": "status", **st.to_dict(), **({} if name == s else {"calibrator": name})})
                next_status[name] = now + status_every
                if on_line:
                    emit(f"{now:9.2f} s  {name:5s}  {'status':10s} [{st.level.name}] {st.message}")
            n += 1
            if n % 1000 == 0:
                bar.set_postfix_str(f"t = {t:.1f} s", refresh=False)
        for name, cal in cals.items():  # a fit the last samples started, run to its end (stream/evaluation.py)
            for ev in cal.finish_fit():
                timeline.append(_event_entry(ev, name))
                if on_line:
                    emit(f"{ev.t:9.2f} s  {name:5s}  {ev.kind.value:10s} {ev.message}")
    if n == 0:  # as the offline readers do: an empty recording is an error, not "final state after 0 messages"
        msg = f"{path} holds no sensor_msgs/Imu or MagneticField messages (or CSV rows) to replay"
        raise RecordingError(msg)
    return {"calibrators": cals, "timeline": timeline, "messages": n,
            "topics": {name: plan[name][2] for name in cals}}


def _event_entry(ev: Event, name: str) -> dict[str, Any]:
    out: dict[str, Any] = {"kind": ev.kind.value, "t": ev.t, "sensor": ev.sensor, "message": ev.message}
    if name != ev.sensor:
        out["calibrator"] = name
    if ev.kind is EventKind.CALIBRATED and ev.calibration is not None:
        out["calibration"] = ev.calibration.to_dict()
    return out
