"""Calibration files: the ``ros__parameters`` YAML the node and ``margcal calibrate`` write and read.

Integrity (format_version 2): the file ends with a YAML comment ``# sha256: <64 hex digits>``, the
SHA-256 of the canonical content (the parsed document as JSON with sorted keys and no spaces), so
the file stays a plain params file for ``--params-file`` while a file cut short (a full disk, a
kill during a copy) or changed after writing is refused instead of loading a wrong norm or losing
a sensor. Comments and formatting may change; values may not.

Old files: format_version 1 was written by ros_margcal 0.1, which had no checksum; a file whose
entries are all version 1 and which has no checksum line is read unchecked. A file with a version 2
entry and no checksum line is refused (a cut file loses its last line first). To keep a deliberate
hand edit of a version 2 file, delete its checksum line and set its ``format_version`` to 1.

Every failure to load is a CalibrationFileError with a one-line message: not a regular file (a
FIFO, a device), larger than 1 MiB, not UTF-8, not YAML, nested too deeply, YAML aliases (which a
calibration file never needs and an alias bomb abuses), a bad checksum, a bad field.

Saving follows symbolic links: a ``calibration_file`` that links to a file on a persistent volume keeps
its link, and the file it points to is replaced atomically (the temporary file is written beside the
link's target, not beside the link, so the rename stays within one file system). A save onto a FIFO, a
device, a directory or a socket (or through a link that points to one, a link loop, a link into a
missing folder) is refused before anything is written, with a CalibrationFileError that is also an
OSError (the node's save handler catches OSError).
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import re
import stat
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from .calibration import Calibration
from .errors import CalibrationFileError, one_line

__all__ = ["calibration_from_yaml", "calibration_to_yaml", "load_calibrations", "read_calibration_file",
           "read_small_text", "save_calibrations", "write_temp"]

Array = NDArray[np.float64]

MAX_BYTES = 1 << 20
"""Largest calibration file read (1 MiB; a real one is about 1 KiB per sensor)."""

_CHECKSUM = re.compile(r"^# sha256: ([0-9a-f]{64})[ \t]*\r?$", re.MULTILINE)
_STALE_TMP_S = 60.0  # a save takes milliseconds: an older temp file of the same target is debris of a killed save


_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$")
"""YAML 1.2's floats with an exponent (``5e-05``, ``1.0e5``), which YAML 1.1 (PyYAML) reads as strings but ROS 2's
parser reads as numbers; YAML 1.1 already reads the others (``0.5``, ``1.0e-05``)."""


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader refusing aliases (a calibration file never has any, and an alias bomb expands when read) and
    reading plain scalars in YAML 1.2's float syntax as floats, as ROS 2 does (a quoted one stays a string)."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not allowed here", mark)
        return super().compose_node(parent, index)


class _Dumper(yaml.SafeDumper):
    """SafeDumper that quotes a string in YAML 1.2's float syntax (``'1e5'``), so ``_StrictLoader`` reads a string back."""


_StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))
_Dumper.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))



def _digest(doc: Any) -> str:
    """SHA-256 of the canonical content: the document as JSON, keys sorted, no spaces."""
    canon = json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True)
    return hashlib.sha256(canon.encode("ascii")).hexdigest()


def _load_yaml(text: str, where: str) -> Any:
    try:
        return yaml.load(text, Loader=_StrictLoader)  # a SafeLoader subclass
    except RecursionError:
        msg = f"{where} is nested too deeply to be a calibration file"
        raise CalibrationFileError(msg) from None
    except Exception as exc:  # YAMLError, and ValueError/OverflowError from scalar constructors (dates, big ints)
        msg = f"{where} is not valid YAML ({one_line(str(exc))}); delete it or restore a backup"
        raise CalibrationFileError(msg) from exc


def _dump(cals: dict[str, Calibration], node: str) -> str:
    doc = {node: {"ros__parameters": {"calibration": {k: c.to_dict() for k, c in cals.items()}}}}
    text = yaml.dump(doc, Dumper=_Dumper, sort_keys=False, default_flow_style=None)
    return f"{text}# sha256: {_digest(_load_yaml(text, '<dump>'))}\n"  # digest of what a reader will parse


def _block(doc: Any, where: str) -> tuple[str, dict[Any, Any]]:
    """The node name and the ``calibration`` block under its ``ros__parameters``."""
    if isinstance(doc, dict):
        for node, node_params in doc.items():
            if isinstance(node_params, dict) and isinstance(node_params.get("ros__parameters"), dict):
                block = node_params["ros__parameters"].get("calibration")
                if isinstance(block, dict) and block:
                    return str(node), block
        msg = f"{where} has no '<node>: ros__parameters: calibration:' block"
        raise CalibrationFileError(msg)
    msg = f"{where} is not a ros__parameters calibration file"
    raise CalibrationFileError(msg)


def _check_integrity(text: str, doc: Any, block: dict[Any, Any], where: str) -> None:
    """Refuse a newer file, a checksum that does not match, and a version 2 file without its checksum line."""
    versions = [e.get("format_version") for e in block.values() if isinstance(e, dict)]
    versions = [v for v in versions if type(v) is int]
    if versions and max(versions) > Calibration.FORMAT_VERSION:
        msg = (f"{where}: calibration format_version {max(versions)} is newer than this ros_margcal understands "
               f"({Calibration.FORMAT_VERSION}); upgrade ros_margcal or refit")
        raise CalibrationFileError(msg)
    sums = _CHECKSUM.findall(text)
    if len(sums) > 1:
        msg = f"{where} has {len(sums)} '# sha256:' lines; a calibration file has one, at its end"
        raise CalibrationFileError(msg)
    if sums:
        try:
            actual = _digest(doc)
        except (TypeError, ValueError, RecursionError) as exc:  # keys or values JSON cannot hold: not ours
            msg = f"{where}: its content cannot be checked against its checksum ({one_line(str(exc))})"
            raise CalibrationFileError(msg) from None
        if actual != sums[0]:
            msg = (f"{where}: checksum mismatch: the file was cut short or changed after it was written; restore a "
                   "backup or refit (to keep a deliberate edit: delete the '# sha256:' line, set format_version: 1)")
            raise CalibrationFileError(msg)
    elif any(v >= 2 for v in versions):
        msg = (f"{where} has no '# sha256:' checksum line although format_version 2 files end with one: "
               "the file was cut short; restore a backup or refit")
        raise CalibrationFileError(msg)


def _parse(text: str, where: str) -> tuple[dict[str, Calibration], str]:
    """The calibrations of a file's text and the node name they are under."""
    doc = _load_yaml(text, where)
    node, block = _block(doc, where)
    _check_integrity(text, doc, block, where)
    cals: dict[str, Calibration] = {}
    for key, entry in block.items():
        try:
            cals[str(key)] = Calibration.from_dict(entry)
        except CalibrationFileError as exc:
            msg = f"{where}: sensor {str(key)!r}: {one_line(str(exc))}"
            raise CalibrationFileError(msg) from exc
    return cals, node


def _pid_alive(pid: int) -> bool:
    if os.name != "posix":  # os.kill(pid, 0) is no probe on Windows: rely on the age rule there
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # PermissionError: alive, another user's
        return True
    return True


def _remove_stale_temps(target: Path) -> None:
    """Delete temp files of earlier saves of ``target`` that were killed before their rename.

    A temp file is named ``.<target>.<pid>.<random>.tmp``; it is debris when its process is gone or
    when it is older than a minute (a save takes milliseconds; this also covers names without a pid).
    A live process's recent temp file is left alone: it may be a save running right now.
    """
    head = f".{target.name}."
    now = time.time()
    for tmp in target.parent.glob(f"{glob.escape(head)}*.tmp"):
        pid_text = tmp.name[len(head) :].split(".", 1)[0]
        with contextlib.suppress(OSError):
            info = tmp.lstat()
            if not stat.S_ISREG(info.st_mode):
                continue
            dead = pid_text.isdigit() and int(pid_text) != os.getpid() and not _pid_alive(int(pid_text))
            if dead or now - info.st_mtime > _STALE_TMP_S:
                tmp.unlink()


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a no-op where directories cannot be opened, e.g. Windows)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class _SaveRefused(CalibrationFileError, OSError):
    """A save refused before writing (a special file, a broken link): bad input, and an OSError for the node."""


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _save_target(given: Path) -> Path:
    """The file a save of ``given`` replaces: ``given`` itself, or the end of its chain of symbolic links.

    Raises _SaveRefused for a link loop, a link into a missing folder, and anything but a regular file.
    """
    where = str(given) if str(given).isprintable() else repr(str(given))
    try:
        target = Path(os.path.realpath(given, strict=False))
        info: os.stat_result | None = target.lstat()
    except FileNotFoundError:
        info = None
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        msg = f"cannot save calibration file {where}: {one_line(str(exc))}"
        raise _SaveRefused(msg) from exc
    if info is not None and stat.S_ISLNK(info.st_mode):  # realpath stops at a loop and returns a link
        msg = f"cannot save calibration file {where}: a loop of symbolic links; point it at a file or remove it"
        raise _SaveRefused(msg)
    via = f" (a link to {target})" if os.path.islink(given) else ""
    if info is not None and not stat.S_ISREG(info.st_mode):
        kind = next((name for test, name in _KINDS if test(info.st_mode)), "not a regular file")
        msg = (f"cannot save calibration file {where}{via}: it is {kind}, not a regular file; "
               "remove it or choose another path")
        raise _SaveRefused(msg)
    if not target.parent.is_dir():
        msg = f"cannot save calibration file {where}{via}: folder {target.parent} does not exist (a volume not mounted?)"
        raise _SaveRefused(msg)
    return target


def save_calibrations(path: str | os.PathLike[str], cals: dict[str, Calibration], node: str = "margcal") -> Path:
    """Write calibrations per sensor atomically (temp file in the same folder, fsync, rename, fsync the folder).

    The file ends with its checksum line; temp files left by earlier killed saves of the same target
    are removed first (``_remove_stale_temps``). A symbolic link is followed: the link stays and the
    file it points to gets the new content (``_save_target``). Returns ``path``.

    Raises:
        CalibrationFileError: (also an OSError) ``path`` is, or links to, a FIFO, a device, a directory or a
            socket, or its links loop or end in a missing folder; nothing is written.
        OSError: the system refuses the write (no permission, a full disk).
    """
    given = Path(path)
    given.parent.mkdir(parents=True, exist_ok=True)
    target = _save_target(given)
    text = _dump(cals, node)
    _remove_stale_temps(target)
    tmp = write_temp(target, text, prefix=f".{target.name}.{os.getpid()}.")
    try:
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_dir(target.parent)
    return given


def write_temp(target: Path, text: str, prefix: str | None = None) -> Path:
    """``text`` in a temporary file beside ``target``, on disk (fsync) and readable like any other file, to be
    renamed over ``target``; removed again when the write fails."""
    fd, tmp = tempfile.mkstemp(prefix=prefix or f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return Path(tmp)


def read_small_text(p: Path, where: str, what: str = "calibration file", limit: int = MAX_BYTES) -> str:
    """The text of ``what`` at ``p``: a regular file (never a FIFO or device, which could block or never end) of at most
    ``limit`` bytes; CalibrationFileError naming it otherwise (a calibration file, a validator file)."""
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        msg = f"cannot read {what} {where}: {one_line(str(exc))}"
        raise CalibrationFileError(msg) from exc
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode) or info.st_size > limit:
        os.close(fd)
        why = "not a regular file" if not stat.S_ISREG(info.st_mode) else f"{info.st_size} bytes, more than {limit}"
        msg = f"cannot read {what} {where}: {why}"
        raise CalibrationFileError(msg)
    with os.fdopen(fd, "rb") as fh:
        try:
            data = fh.read(limit + 1)
        except OSError as exc:
            msg = f"cannot read {what} {where}: {one_line(str(exc))}"
            raise CalibrationFileError(msg) from exc
    if len(data) > limit:
        msg = f"cannot read {what} {where}: more than {limit} bytes"
        raise CalibrationFileError(msg)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        msg = f"cannot read {what} {where}: not UTF-8 ({exc})"
        raise CalibrationFileError(msg) from exc


def load_calibrations(path: str | os.PathLike[str]) -> dict[str, Calibration]:
    """Read the calibrations of a file written by ``save_calibrations``; CalibrationFileError if unusable."""
    return read_calibration_file(path)[0]


def read_calibration_file(path: str | os.PathLike[str]) -> tuple[dict[str, Calibration], str]:
    """``load_calibrations`` and the node name the calibrations are under: a file written again keeps it (the node
    writes its own name; ``margcal calibrate -o`` into a node's file kept the other sensor's calibration but renamed
    the node ``margcal``). CalibrationFileError if unusable."""
    try:
        p = Path(path)
    except TypeError as exc:
        msg = f"calibration file path must be a path, got {type(path).__name__}"
        raise CalibrationFileError(msg) from exc
    where = str(p) if str(p).isprintable() else repr(str(p))
    return _parse(read_small_text(p, where), where)


def calibration_to_yaml(cal: Calibration, node: str = "margcal") -> str:
    """One calibration alone as a ``ros__parameters`` YAML document (with its checksum line)."""
    return _dump({cal.sensor or "sensor": cal}, node)


def calibration_from_yaml(text: str, sensor: str | None = None) -> Calibration:
    """Read one calibration from YAML text (the only one, or the one named ``sensor``)."""
    cals = _parse(text, "<text>")[0]
    if sensor is None:
        if len(cals) != 1:
            msg = f"YAML holds calibrations for {sorted(cals)}; name the sensor to read"
            raise CalibrationFileError(msg)
        return next(iter(cals.values()))
    if sensor not in cals:
        msg = f"YAML holds no calibration for sensor {sensor!r} (has {sorted(cals)})"
        raise CalibrationFileError(msg)
    return cals[sensor]
