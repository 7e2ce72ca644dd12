"""CSV recordings: header ``t,x,y,z`` (seconds, raw units), optional ``temp`` and ``gx,gy,gz``."""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..model.errors import RecordingError
from .recording import Recording, check_order, check_stamps

__all__ = ["guess_sensor", "read_csv", "write_csv"]

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


# -- CSV -------------------------------------------------------------------------------------------


def guess_sensor(path: Path) -> str:
    name = path.stem.lower()
    if "mag" in name:
        return "mag"
    if "acc" in name:
        return "accel"
    return ""


def read_csv(path: Path, sensor: str | None, order: str) -> Recording:
    """The CSV at ``path``; ``order`` as ``read.read_recording`` takes it (check, sort or file)."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:  # -sig: a spreadsheet export starts with a BOM
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:  # csv.Error: a cell over the 128 KiB field limit, a NUL
        msg = f"cannot read {path}: {exc}"
        raise RecordingError(msg) from exc
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        msg = f"{path} is empty; expected a header row 't,x,y,z' and samples"
        raise RecordingError(msg)
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in ("t", "x", "y", "z") if c not in header]
    if missing:
        msg = f"{path}: bad header {rows[0]!r}: missing column(s) {missing}; expected 't,x,y,z' [,temp] [,gx,gy,gz]"
        raise RecordingError(msg)
    gyro_cols = [c for c in ("gx", "gy", "gz") if c in header]
    if gyro_cols and len(gyro_cols) != 3:
        msg = f"{path}: bad header {rows[0]!r}: gyro needs all of gx,gy,gz, found {gyro_cols}"
        raise RecordingError(msg)
    if len(set(header)) != len(header):
        msg = f"{path}: bad header {rows[0]!r}: repeated column names"
        raise RecordingError(msg)
    if len(rows) < 2:
        msg = f"{path} has a header but no samples"
        raise RecordingError(msg)
    wanted = ["t", "x", "y", "z"] + (["temp"] if "temp" in header else []) + gyro_cols
    cols = [header.index(c) for c in wanted]
    data = np.empty((len(rows) - 1, len(wanted)))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            msg = f"{path}: line {i + 2} has {len(row)} cells, the header {len(header)}"
            raise RecordingError(msg)
        for j, c in enumerate(cols):
            try:
                if "_" in row[c]:  # float() reads '1_0e-6' as a Python literal, 1e-5: a typo in a CSV
                    raise ValueError(row[c])
                data[i, j] = float(row[c])
            except ValueError:
                msg = f"{path}: line {i + 2}, column {wanted[j]!r}: {row[c]!r} is not a number"
                raise RecordingError(msg) from None
    bad = ~np.isfinite(data)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        n_bad = int(bad.any(axis=1).sum())
        msg = f"{path}: line {i + 2}, column {wanted[j]!r} is {float(data[i, j])}; {n_bad} row(s) are not finite, remove them"
        raise RecordingError(msg)
    check_stamps(data[:, 0], str(path))
    index = None if order == "file" else check_order(data[:, 0], str(path), order == "sort")
    if index is not None:
        data = data[index]
    k = 4
    temp = None
    if "temp" in wanted:
        temp, k = data[:, 4].copy(), 5
    gyro = data[:, k : k + 3].copy() if gyro_cols else None
    return Recording(t=data[:, 0].copy(), raw=data[:, 1:4].copy(), gyro=gyro, temp=temp,
                     sensor=sensor if sensor is not None else guess_sensor(path))


def write_csv(path: str | os.PathLike[str], rec: Recording) -> Path:
    """Write ``t,x,y,z`` (+ ``temp``, + ``gx,gy,gz`` when present) with full float precision."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    cols = [rec.t[:, None], rec.raw]
    names = ["t", "x", "y", "z"]
    if rec.temp is not None:
        cols.append(rec.temp[:, None])
        names.append("temp")
    if rec.gyro is not None:
        cols.append(rec.gyro)
        names += ["gx", "gy", "gz"]
    np.savetxt(target, np.hstack(cols), fmt="%.17g", delimiter=",", header=",".join(names), comments="")
    return target


# -- rosbag2 ---------------------------------------------------------------------------------------
