"""Reading and writing recordings: CSV files and rosbag2 bags (.mcap, .db3) through ``rosbags``.

CSV: a header row naming the columns ``t,x,y,z`` (seconds, raw units), optionally ``temp`` (°C) and
``gx,gy,gz`` (rad/s), in any order; other columns are ignored. Every cell must be a finite number.

rosbag2: ``sensor_msgs/msg/Imu`` gives an accelerometer recording (``linear_acceleration``, m/s²,
with ``angular_velocity`` as gyro) and ``sensor_msgs/msg/MagneticField`` a magnetometer one
(tesla), per REP-145/REP-103. The time of a sample is its header stamp, or the bag's receive time
when the stamp is zero (unset). ``sensor_msgs/msg/Temperature`` on ``<topic>/temperature`` is
interpolated onto the samples. A bag is either a rosbag2
directory (``metadata.yaml`` plus storage files) or a bare ``.mcap`` / ``.db3`` storage file, told by its
first bytes (the MCAP magic, the SQLite header) or else by its suffix in any case (``IMU.MCAP``); rosbags
picks the storage by a lower-case suffix, so a file named otherwise is opened through a link named so.
A directory without ``metadata.yaml`` is refused naming the storage file in it to pass instead.

Time order: offline readers refuse a recording whose times go backwards (``RecordingError`` naming
the first offending row and the count) unless ``sort=True`` (``order="sort"``) is given, which sorts the
samples stably and logs how many were out of order, or ``order="file"``, which keeps the recorded order and
stamps (a clock restart; ``recording.continue_clock`` makes them non-decreasing). Repeated times are kept.
``iter_bag_messages`` streams in bag order and leaves the checking to its consumer (the streaming
pipeline counts such samples).

Writing follows REP-145 for ``imu/data_raw``: no orientation (``orientation_covariance[0] = -1``),
no gyro when the recording has none (``angular_velocity_covariance[0] = -1``), and an all-zero
covariance ("unknown") for the measured vectors; ``frame_id`` is ``imu_link``.
"""

from __future__ import annotations

import heapq
import logging
import os
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.errors import RecordingError, one_line
from .recording import Recording, check_order, check_stamps

__all__ = ["BAG_SUFFIXES", "FRAME_ID", "BagMessage", "bag_topics", "is_bag", "iter_bag_messages", "write_bag"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

FRAME_ID = "imu_link"
BAG_SUFFIXES = (".mcap", ".db3")
_MAGIC = ((b"\x89MCAP", ".mcap"), (b"SQLite format 3\x00", ".db3"))
"""A storage file's first bytes and the suffix rosbags reads it by."""
IMU = "sensor_msgs/msg/Imu"
MAG = "sensor_msgs/msg/MagneticField"
TEMPERATURE = "sensor_msgs/msg/Temperature"
_KIND_OF_TYPE = {IMU: "imu", MAG: "mag"}
_SENSOR_OF_KIND = {"imu": "accel", "mag": "mag"}
_KIND_OF_SENSOR = {"accel": "imu", "mag": "mag"}


@dataclass(frozen=True, slots=True)
class BagMessage:
    """One sensor message of a bag; unpacks as ``t, kind, xyz, gyro, msg`` (the topic is ``.topic``).

    Attributes:
        t: header stamp in seconds (the receive time when the stamp is unset).
        kind: "imu" (sensor_msgs/Imu) or "mag" (sensor_msgs/MagneticField).
        xyz: linear acceleration (m/s²) or magnetic field (T), shape (3,).
        gyro: angular velocity (rad/s), shape (3,), or None (MagneticField, or no gyro in the Imu).
        msg: the deserialised message (rosbags Jazzy type: header, covariances, ...).
        topic: the topic it was recorded on.
    """

    t: float
    kind: str
    xyz: Array
    gyro: Array | None
    msg: Any
    topic: str = ""

    def __iter__(self) -> Iterator[Any]:
        return iter((self.t, self.kind, self.xyz, self.gyro, self.msg))


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore  # optional dependency: bags only (a ROS install may lack rosbags)

    return get_typestore(Stores.ROS2_JAZZY)


def _storage_suffix(path: Path) -> str:
    """The suffix rosbags reads a bare storage file by: its content's (first bytes), else its own in lower case
    if that is .mcap or .db3, else "" (no storage file: a CSV, or a file that cannot be read)."""
    if path.is_file():  # a regular file only: reading a FIFO would block
        try:
            with path.open("rb") as fh:
                head = fh.read(16)
        except OSError:
            head = b""
        for magic, suffix in _MAGIC:
            if head.startswith(magic):
                return suffix
    suffix = path.suffix.lower()
    return suffix if suffix in BAG_SUFFIXES else ""


def is_bag(path: Path) -> bool:
    """A rosbag2 directory or a bare .mcap / .db3 storage file (by its first bytes, else its suffix in any case)."""
    return path.is_dir() or bool(_storage_suffix(path))


def _no_metadata(path: Path) -> str:
    """Why a directory without metadata.yaml is no bag, and the storage file in it to pass instead."""
    found = sorted(str(f) for f in path.iterdir() if f.is_file() and _storage_suffix(f))
    if found:
        more = f" (or one of the {len(found) - 1} others)" if len(found) > 1 else ""
        return f"{path} is a directory without metadata.yaml, so no rosbag2 bag; pass its storage file: {found[0]}{more}"
    return (f"{path} is a directory without metadata.yaml and has no .mcap or .db3 file: no recording; pass a rosbag2 "
            "bag directory, a .mcap / .db3 file or a CSV file")


def _open_reader(path: Path) -> Any:
    from rosbags.rosbag2 import Reader  # optional dependency: bags only (a ROS install may lack rosbags)

    if not path.exists():
        msg = f"recording {path} does not exist"
        raise RecordingError(msg)
    if path.is_dir() and not (path / "metadata.yaml").exists():
        raise RecordingError(_no_metadata(path))
    suffix = "" if path.is_dir() else _storage_suffix(path)
    link_dir = None
    try:
        opened = path
        if suffix and path.suffix != suffix:  # rosbags picks the storage by a lower-case suffix: a link named so
            link_dir = Path(tempfile.mkdtemp(prefix=".margcal-bag-"))
            opened = link_dir / f"bag{suffix}"
            opened.symlink_to(path.resolve())
        reader = Reader(opened)
        reader.open()
    except Exception as exc:  # rosbags raises ReaderError, but also KeyError/struct/apsw errors on junk
        if link_dir is not None:
            shutil.rmtree(link_dir, ignore_errors=True)
        rename = f"; or rename it to {path.with_suffix(suffix)}" if link_dir is not None else ""
        msg = f"{path} is not a readable rosbag2 bag ({type(exc).__name__}: {one_line(exc)}){rename}"
        raise RecordingError(msg) from exc
    reader.margcal_link_dir = link_dir  # removed by _close
    return reader


def _close(reader: Any) -> None:
    """Close a reader; a failure to close a corrupt file after reading is logged, not raised over the real error.
    The link ``_open_reader`` made for a file rosbags would not open by its name is removed."""
    try:
        reader.close()
    except Exception as exc:  # the reader of a corrupt file may fail again on close
        log.debug("closing the bag reader failed: %s: %s", type(exc).__name__, exc)
    finally:
        link_dir = getattr(reader, "margcal_link_dir", None)
        if link_dir is not None:
            shutil.rmtree(link_dir, ignore_errors=True)



def bag_topics(path: str | os.PathLike[str]) -> dict[str, str]:
    """Topic -> message type of a bag."""
    reader = _open_reader(Path(path))
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        _close(reader)


def _stamp(msg: Any, log_ns: int) -> float:
    st = msg.header.stamp
    if st.sec == 0 and st.nanosec == 0:
        return log_ns * 1e-9
    return float(st.sec + st.nanosec * 1e-9)


def _vec(v: Any) -> Array:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def _convert(msg: Any, kind: str, log_ns: int, topic: str) -> BagMessage:
    if kind == "imu":
        gyro = None if msg.angular_velocity_covariance[0] == -1 else _vec(msg.angular_velocity)
        return BagMessage(_stamp(msg, log_ns), kind, _vec(msg.linear_acceleration), gyro, msg, topic)
    return BagMessage(_stamp(msg, log_ns), kind, _vec(msg.magnetic_field), None, msg, topic)


def _short(path: Path, conn: Any, read: int) -> str:
    """Why ``read`` messages of ``conn`` are not all the bag's index lists ("" when they are, or it lists none): a
    corrupt chunk the reader skips without an error (a flipped bit in an MCAP's message index lost 93 of 3000)."""
    listed = int(getattr(conn, "msgcount", 0) or 0)
    if read >= listed:
        return ""
    return (f"{path}: topic {conn.topic!r} gave {read} of the {listed} messages the bag's index lists: the bag is "
            "corrupt or cut short (or its index stale)")


def iter_bag_messages(path: str | os.PathLike[str], *, topics: set[str] | None = None) -> Iterator[BagMessage]:
    """Stream the Imu and MagneticField messages of a bag in bag (receive-time) order.

    Args:
        path: rosbag2 directory or .mcap / .db3 file.
        topics: only these topics (default: every Imu and MagneticField topic).

    Yields:
        BagMessage, unpacking as ``(t, kind, xyz, gyro, msg)`` with ``.topic``; gyro is None for
        MagneticField and for an Imu whose ``angular_velocity_covariance[0]`` is -1.

    Raises:
        RecordingError: missing or unreadable bag, or no matching topic.
    """
    p = Path(path)
    reader = _open_reader(p)
    try:
        conns = [c for c in reader.connections if c.msgtype in _KIND_OF_TYPE and (topics is None or c.topic in topics)]
        if not conns:
            have = {c.topic: c.msgtype for c in reader.connections}
            msg = f"{p} has no Imu or MagneticField topic{' among ' + str(sorted(topics)) if topics else ''}; it has {have}"
            raise RecordingError(msg)
        store = _typestore()
        messages = reader.messages(connections=conns)
        read = {c.id: 0 for c in conns}
        while True:
            try:  # a corrupt storage file fails here (apsw.CorruptError, a zstd error, a CDR error): the reader's fault
                conn, log_ns, data = next(messages)
                item = _convert(store.deserialize_cdr(data, conn.msgtype), _KIND_OF_TYPE[conn.msgtype], log_ns, conn.topic)
                read[conn.id] += 1
            except StopIteration:
                for c in conns:  # a stream takes what arrives, as the node does: said, not refused
                    why = _short(p, c, read[c.id])
                    if why:
                        log.warning("%s; the rest was replayed", why)
                return
            except Exception as exc:
                msg = f"{p}: cannot read messages ({type(exc).__name__}: {one_line(exc)}); the bag is corrupt or cut short"
                raise RecordingError(msg) from exc
            yield item  # outside the try: an error of the consumer is not the bag's
    finally:
        _close(reader)


def _pick_connection(path: Path, conns: list[Any], sensor: str | None, topic: str | None) -> Any:
    have = {c.topic: c.msgtype for c in conns}
    if topic is not None:
        match = [c for c in conns if c.topic == topic]
        if not match or match[0].msgtype not in _KIND_OF_TYPE:
            msg = f"{path} has no Imu or MagneticField topic {topic!r}; it has {have}"
            raise RecordingError(msg)
        if sensor is not None and _SENSOR_OF_KIND[_KIND_OF_TYPE[match[0].msgtype]] != sensor:
            msg = f"{path}: topic {topic!r} is {match[0].msgtype}, not a {sensor!r} sensor"
            raise RecordingError(msg)
        return match[0]
    kinds = {_KIND_OF_SENSOR[sensor]} if sensor is not None else set(_SENSOR_OF_KIND)
    match = [c for c in conns if _KIND_OF_TYPE.get(c.msgtype) in kinds]
    if not match:
        what = {"imu": "Imu", "mag": "MagneticField"}
        msg = f"{path} has no {' or '.join(what[k] for k in sorted(kinds))} topic; it has {have}"
        raise RecordingError(msg)
    if len(match) > 1:
        msg = (f"{path} has several matching topics {sorted(c.topic for c in match)}; choose one with --topic / topic= "
               "(or --sensor / sensor=)")
        raise RecordingError(msg)
    return match[0]


def read_bag(path: Path, sensor: str | None, topic: str | None, order: str) -> Recording:
    """One topic of a bag; ``order`` as ``read.read_recording`` takes it (check, sort or file)."""
    reader = _open_reader(path)
    try:
        conn = _pick_connection(path, list(reader.connections), sensor, topic)
        kind = _KIND_OF_TYPE[conn.msgtype]
        named = [c for c in reader.connections if c.msgtype == TEMPERATURE and c.topic == f"{conn.topic}/temperature"]
        temp_conn = named[0] if named else None
        store = _typestore()
        t: list[float] = []
        xyz: list[Array] = []
        gyro: list[Array | None] = []
        tt: list[float] = []
        tv: list[float] = []
        wanted = [conn] + ([temp_conn] if temp_conn is not None else [])
        for c, log_ns, data in reader.messages(connections=wanted):
            msg = store.deserialize_cdr(data, c.msgtype)
            if c is temp_conn:
                tt.append(_stamp(msg, log_ns))
                tv.append(float(msg.temperature))
                continue
            m = _convert(msg, kind, log_ns, c.topic)
            t.append(m.t)
            xyz.append(m.xyz)
            gyro.append(m.gyro)
    except RecordingError:
        raise
    except Exception as exc:
        msg = f"{path}: cannot read messages ({type(exc).__name__}: {one_line(exc)}); the bag is corrupt or cut short"
        raise RecordingError(msg) from exc
    finally:
        _close(reader)
    if not t:
        msg = f"{path}: topic {conn.topic!r} holds no messages"
        raise RecordingError(msg)
    short = _short(path, conn, len(t))
    if short:  # a batch fit of part of a corrupt bag, whose values may be flipped too: refused
        msg = f"{short}; nothing is fitted from part of it"
        raise RecordingError(msg)
    times = np.array(t)
    raw = np.array(xyz)
    gy = np.array(gyro) if all(g is not None for g in gyro) else None
    if not (np.isfinite(times).all() and np.isfinite(raw).all()):
        msg = f"{path}: topic {conn.topic!r} has NaN/Inf samples; remove them"
        raise RecordingError(msg)
    check_stamps(times, f"{path} {conn.topic}")
    index = None if order == "file" else check_order(times, f"{path} {conn.topic}", order == "sort")
    if index is not None:
        times, raw = times[index], raw[index]
        gy = None if gy is None else gy[index]
    temp = None
    if tt:
        ti, vi = np.array(tt), np.array(tv)
        srt = np.argsort(ti, kind="stable")
        temp = np.interp(times, ti[srt], vi[srt])
    return Recording(t=times, raw=raw, gyro=gy, temp=temp, sensor=_SENSOR_OF_KIND[kind],
                     unit="m/s^2" if kind == "imu" else "T")


def _stamp_msg(store: Any, t: float) -> Any:
    ns = round(t * 1e9)
    time_cls = store.types["builtin_interfaces/msg/Time"]
    return store.types["std_msgs/msg/Header"](stamp=time_cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                                              frame_id=FRAME_ID)


def _messages(store: Any, rec: Recording, kind: str) -> Iterator[tuple[int, Any]]:
    v3 = store.types["geometry_msgs/msg/Vector3"]
    zero = np.zeros(9)
    absent = np.array([-1.0] + [0.0] * 8)
    if kind == "mag":
        cls = store.types[MAG]
        for i in range(len(rec)):
            x, y, z = rec.raw[i]
            yield round(rec.t[i] * 1e9), cls(header=_stamp_msg(store, rec.t[i]),
                                              magnetic_field=v3(x=x, y=y, z=z), magnetic_field_covariance=zero)
        return
    cls = store.types[IMU]
    quat = store.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    for i in range(len(rec)):
        x, y, z = rec.raw[i]
        if rec.gyro is None:
            av, av_cov = v3(x=0.0, y=0.0, z=0.0), absent
        else:
            gx, gy, gz = rec.gyro[i]
            av, av_cov = v3(x=gx, y=gy, z=gz), zero
        yield round(rec.t[i] * 1e9), cls(header=_stamp_msg(store, rec.t[i]), orientation=quat,
                                          orientation_covariance=absent, angular_velocity=av,
                                          angular_velocity_covariance=av_cov, linear_acceleration=v3(x=x, y=y, z=z),
                                          linear_acceleration_covariance=zero)


def _temperature_messages(store: Any, rec: Recording) -> Iterator[tuple[int, Any]]:
    cls = store.types[TEMPERATURE]
    assert rec.temp is not None
    for i in range(len(rec)):
        yield round(rec.t[i] * 1e9), cls(header=_stamp_msg(store, rec.t[i]), temperature=float(rec.temp[i]), variance=0.0)


def _tagged(index: int, conn: Any, items: Iterator[tuple[int, Any]]) -> Iterator[tuple[int, int, Any, Any]]:
    for ns, msg in items:
        yield ns, index, conn, msg


def write_bag(
    path: str | os.PathLike[str],
    recs: dict[str, Recording],
    *,
    storage: str = "mcap",
    overwrite: bool = False,
) -> Path:
    """Write recordings as real sensor_msgs messages (ROS 2 Jazzy types) into a rosbag2 bag.

    Args:
        path: a path ending in .mcap / .db3 writes one bare storage file (zstd-chunked for mcap);
            any other path becomes a rosbag2 directory with ``metadata.yaml``.
        recs: topic -> recording; "accel" recordings become Imu, "mag" ones MagneticField; a
            recording's ``temp`` goes to ``<topic>/temperature`` (sensor_msgs/Temperature).
        storage: "mcap" or "sqlite3" (for a directory; a file's suffix decides for a file).
        overwrite: replace an existing target.

    Raises:
        RecordingError: no recordings, unknown storage, a recording without a sensor, an existing target.
    """
    # optional dependency: bags only (a ROS install may lack rosbags)
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    target = Path(path)
    if target.suffix in BAG_SUFFIXES:
        storage = "mcap" if target.suffix == ".mcap" else "sqlite3"
    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        msg = f"storage must be 'mcap' or 'sqlite3', got {storage!r}"
        raise RecordingError(msg)
    if not recs:
        msg = f"nothing to write to {target}: recs is empty"
        raise RecordingError(msg)
    for topic, rec in recs.items():
        if rec.sensor not in _KIND_OF_SENSOR:
            msg = f"recording for {topic!r} has sensor {rec.sensor!r}; set 'mag' or 'accel' to write a bag"
            raise RecordingError(msg)
    if target.exists():
        if not overwrite:
            msg = f"{target} exists already; pass overwrite=True (--force) to replace it"
            raise RecordingError(msg)
        if target.is_dir():
            shutil.rmtree(target)
        else:
            target.unlink()
    target.parent.mkdir(parents=True, exist_ok=True)
    store = _typestore()
    single = target.suffix in BAG_SUFFIXES
    workdir = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent)) if single else None
    bagdir = workdir / target.stem if workdir is not None else target
    try:
        writer = Writer(bagdir, version=9, storage_plugin=plugins[storage])
        if storage == "mcap":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        streams: list[Iterator[tuple[int, int, Any, Any]]] = []
        with writer:
            for topic, rec in recs.items():
                kind = _KIND_OF_SENSOR[rec.sensor]
                conn = writer.add_connection(topic, IMU if kind == "imu" else MAG, typestore=store)
                streams.append(_tagged(len(streams), conn, _messages(store, rec, kind)))
                if rec.temp is not None:
                    tconn = writer.add_connection(f"{topic}/temperature", TEMPERATURE, typestore=store)
                    streams.append(_tagged(len(streams), tconn, _temperature_messages(store, rec)))
            for ns, _, conn, msg in heapq.merge(*streams, key=lambda item: (item[0], item[1])):
                writer.write(conn, ns, store.serialize_cdr(msg, conn.msgtype))  # receive order
        if workdir is not None:
            produced = [f for f in bagdir.iterdir() if f.suffix in BAG_SUFFIXES]
            if len(produced) != 1:
                msg = f"rosbags wrote {len(produced)} storage files to {bagdir}; expected one"
                raise RecordingError(msg)
            os.replace(produced[0], target)
    except RecordingError:
        raise
    except Exception as exc:
        msg = f"cannot write {target} ({type(exc).__name__}: {exc})"
        raise RecordingError(msg) from exc
    finally:
        if workdir is not None:
            shutil.rmtree(workdir, ignore_errors=True)
    return target
