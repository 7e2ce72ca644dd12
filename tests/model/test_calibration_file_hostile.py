"""Calibration files under hostile conditions: cut, corrupted, mistyped, absurd, special files, killed saves.

Every failure to load must be a one-line CalibrationFileError naming the problem; nothing else may
escape, nothing may load wrong, and a killed save must not leave debris forever.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from ros_margcal.model.calibration import Calibration, FitStats
from ros_margcal.model.calibration_file import (
    MAX_BYTES,
    calibration_from_yaml,
    calibration_to_yaml,
    load_calibrations,
    save_calibrations,
)
from ros_margcal.model.errors import CalibrationFileError

SHIPPED_TRUTH = Path(__file__).resolve().parents[2] / "ros_margcal" / "data" / "example_truth.yaml"


@pytest.fixture
def two_sensors() -> dict[str, Calibration]:
    """A fitted-looking magnetometer (stats, covariance) and an accelerometer: every field a file holds."""
    names = ("b_x", "b_y", "b_z", "norm")
    mag = Calibration(
        np.array([1.25e-5, -2.5e-6, 3.75e-6]), np.array([[1.02, 0.01, 0.0], [0.01, 0.98, 0.002], [0.0, 0.002, 1.0]]),
        4.9159e-05, model="sym", method="lm", sensor="mag", unit="T",
        stats=FitStats(n_points=380, rms=2.3e-7, max_abs=9.1e-7, rms_relative=0.0047, iterations=7, cost=1.5e-11),
        covariance=np.diag([1e-16, 2e-16, 3e-16, 4e-18]), parameter_names=names, stamp=342.64,
    )  # fmt: skip
    accel = Calibration(np.array([-0.403, 0.476, 0.311]), np.diag([1.046, 0.997, 0.992]), 9.80665, model="diag",
                        method="lin_auto", sensor="accel", unit="m/s^2", stamp=358.69)  # fmt: skip
    return {"mag": mag, "accel": accel}


def _entries(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())["margcal"]["ros__parameters"]["calibration"]


def _legacy_text(entry: dict[str, Any]) -> str:
    """A format_version 1 file (no checksum line, as ros_margcal 0.1 wrote) holding one entry."""
    doc = {"margcal": {"ros__parameters": {"calibration": {"mag": entry}}}}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def _refused(path: Path, match: str | None = None) -> str:
    """Load ``path``, expect a one-line CalibrationFileError (matching ``match``), return its message."""
    with pytest.raises(CalibrationFileError, match=match) as info:
        load_calibrations(path)
    text = str(info.value)
    assert text and "\n" not in text, text
    return text


# -- integrity: a cut or changed file is refused -------------------------------------------------------------------


def test_every_truncation_is_refused(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """Each byte-offset prefix of a saved two-sensor file is refused, or (full content) loads identical to the original."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    data = path.read_bytes()
    original = {k: c.to_dict() for k, c in load_calibrations(path).items()}
    assert set(original) == {"mag", "accel"}
    cut = tmp_path / "cut.yaml"
    loaded = []
    for n in range(len(data)):
        cut.write_bytes(data[:n])
        try:
            back = load_calibrations(cut)
        except CalibrationFileError as exc:
            assert "\n" not in str(exc)
            continue
        assert {k: c.to_dict() for k, c in back.items()} == original, f"cut at byte {n} of {len(data)} loads differently"
        loaded.append(n)
    assert loaded == [len(data) - 1]  # only the final newline may go: the checksum line is then still whole


def test_file_ends_with_the_checksum_of_its_content(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """A saved file is version 2, a readable ros__parameters YAML, and its last line is its checksum comment."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    lines = path.read_text().splitlines()
    assert lines[-1].startswith("# sha256: ") and len(lines[-1]) == len("# sha256: ") + 64
    assert {e["format_version"] for e in _entries(path).values()} == {Calibration.FORMAT_VERSION} == {2}


def test_a_changed_value_is_refused(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """Changing one digit of the norm breaks the checksum; the message says what happened and what to do."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    path.write_text(path.read_text().replace("norm: 4.9159e-05", "norm: 4.9158e-05"))
    assert "restore a backup" in _refused(path, "checksum mismatch")


def test_formatting_and_comments_may_change(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """The checksum covers the content, not the bytes: a comment, CRLF line ends and flow style still load."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    text = path.read_text()
    body, checksum = text[: text.index("# sha256:")], text[text.index("# sha256:") :]
    reflowed = yaml.safe_dump(yaml.safe_load(body), default_flow_style=True)
    path.write_text("# robot 7, fitted in the lab\n" + reflowed.replace("\n", "\r\n") + checksum)
    back = load_calibrations(path)
    assert back["mag"].allclose(two_sensors["mag"], rtol=0) and back["mag"].stats == two_sensors["mag"].stats


def test_a_version_2_file_without_its_checksum_is_refused(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """The checksum line is the last thing written: without it a version 2 file is a cut file."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    path.write_text(path.read_text().rsplit("# sha256:", 1)[0])
    _refused(path, "no '# sha256:' checksum line")


def test_two_checksum_lines_are_refused(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """Two files concatenated (or a pasted line) are not one calibration file."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    path.write_text(path.read_text() + path.read_text().splitlines()[-1] + "\n")
    _refused(path, "2 '# sha256:' lines")


def test_old_files_without_checksum_still_load(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """Format_version 1 files (written before checksums existed), the shipped example truth among them, load unchecked."""
    truth = load_calibrations(SHIPPED_TRUTH)
    assert set(truth) == {"accel", "mag_before", "mag_after"} and truth["mag_after"].stamp == 180.0
    entry = two_sensors["mag"].to_dict() | {"format_version": 1}
    path = tmp_path / "old.yaml"
    path.write_text(_legacy_text(entry))
    assert load_calibrations(path)["mag"].allclose(two_sensors["mag"], rtol=0)


def test_newer_version_is_refused_before_its_checksum(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """A newer file may check itself differently: it is refused as newer, not as corrupt."""
    path = save_calibrations(tmp_path / "cal.yaml", two_sensors)
    path.write_text(path.read_text().replace("format_version: 2", "format_version: 3"))
    _refused(path, "newer than this ros_margcal")


def test_message_yaml_round_trips_with_its_checksum(two_sensors: dict[str, Calibration]) -> None:
    """The calibration topic's YAML text carries the same check: a cut message is refused."""
    text = calibration_to_yaml(two_sensors["mag"])
    assert calibration_from_yaml(text).allclose(two_sensors["mag"], rtol=0)
    with pytest.raises(CalibrationFileError, match="checksum"):
        calibration_from_yaml(text[: text.index("norm:")] + "# sha256: " + text.rsplit("# sha256: ", 1)[1])


# -- strict fields: wrong types and absurd values are refused at load, naming the field ----------------------------


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"format_version": True}, "format_version"),
        ({"format_version": 0}, "format_version"),
        ({"format_version": -7}, "format_version"),
        ({"format_version": "1"}, "format_version"),
        ({"norm": True}, "'norm'"),
        ({"norm": "4.9159e-05"}, "'norm'"),
        ({"norm": 1e-300}, "'norm'"),
        ({"norm": float("inf")}, "'norm'"),
        ({"offset": [1e300, 0.0, 0.0]}, r"'offset\[0\]'"),
        ({"offset": ["0", 0.0, 0.0]}, r"'offset\[0\]'"),
        ({"offset": [0.0, 0.0]}, "'offset'"),
        ({"matrix": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, float("nan")]}, r"'matrix\[8\]'"),
        ({"stamp": float("nan")}, "'stamp'"),
        ({"stamp": float("-inf")}, "'stamp'"),
        ({"stamp": "12.5"}, "'stamp'"),
        ({"covariance": [float("nan")] + [0.0] * 15}, r"'covariance\[0\]'"),
        ({"covariance": [1.0] * 4}, "'covariance'"),
        ({"parameter_names": "b_x"}, "'parameter_names'"),
        ({"sensor": 5}, "'sensor'"),
        ({"model": None}, "'model'"),
        ({"model": "full"}, "model must be one of"),
        ({"stats": {"n_points": "many", "rms": 0.1, "max_abs": 0.3, "rms_relative": 0.01}}, "stats.n_points"),
        ({"stats": {"n_points": 10, "rms": "0.1", "max_abs": 0.3, "rms_relative": 0.01}}, "stats.rms"),
        ({"stats": {"n_points": 10, "rms": 0.1, "max_abs": 0.3, "rms_relative": 0.01, "converged": "yes"}}, "stats.converged"),
        ({"stats": {"n_points": 10, "rms": -0.1, "max_abs": 0.3, "rms_relative": 0.01}}, "stats.rms"),
        ({"stats": {"n_points": 10, "rms": 0.1}}, "'stats' has unknown keys"),
        ({"stats": {"n_points": 10, "rms": 0.1, "max_abs": 0.3, "rms_relative": 0.01, "extra": 1}}, "'stats' has unknown keys"),
        ({"stats": [1, 2]}, "'stats' must be a mapping"),
    ],
)
def test_lenient_values_are_refused(tmp_path: Path, two_sensors: dict[str, Calibration], change: dict[str, Any], field: str) -> None:
    """Booleans, numeric strings, NaN/Inf, absurd magnitudes and mistyped stats are refused, naming the field."""
    entry = two_sensors["mag"].to_dict() | {"format_version": 1} | change
    path = tmp_path / "cal.yaml"
    path.write_text(_legacy_text(entry))
    assert "sensor 'mag'" in _refused(path, field)


def test_wrong_stats_are_refused_at_load_not_at_save(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """A stats block of strings used to load and then break save_calibrations: now the load refuses it."""
    entry = two_sensors["mag"].to_dict() | {"format_version": 1}
    entry["stats"] = {k: str(v) for k, v in entry["stats"].items()}
    path = tmp_path / "cal.yaml"
    path.write_text(_legacy_text(entry))
    _refused(path, "stats")


# -- what is not a calibration file at all --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[" * 600, "nested too deeply|not valid YAML"),
        ("a: &x [1, 2]\nb: *x\n", "aliases"),
        ("margcal:\n  ros__parameters:\n    calibration:\n      mag: 2001-13-45\n", "not valid YAML|mapping"),
        ("\x00\x01binary", "not valid YAML"),
        ("", "not a ros__parameters"),
    ],
)
def test_junk_text_is_refused(tmp_path: Path, text: str, match: str) -> None:
    """Deep nesting, aliases, bad scalars, control characters and an empty file: one-line CalibrationFileErrors."""
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    _refused(path, match)


def test_not_utf8_is_refused(tmp_path: Path) -> None:
    """Latin-1 bytes are not a calibration file."""
    path = tmp_path / "cal.yaml"
    path.write_bytes(b"margcal: \xe9\xff\n")
    _refused(path, "not UTF-8")


def test_a_large_file_is_refused_unread(tmp_path: Path) -> None:
    """More than 1 MiB is no calibration file (a real one is about 1 KiB per sensor)."""
    path = tmp_path / "cal.yaml"
    path.write_text("# padding\n" * (MAX_BYTES // 10 + 1))
    _refused(path, "more than")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    """A FIFO at the path would block a plain read forever; it is refused at once (no writer needed)."""
    path = tmp_path / "cal.yaml"
    os.mkfifo(path)
    _refused(path, "not a regular file")


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_a_device_is_refused(tmp_path: Path) -> None:
    """/dev/zero would be read until memory runs out; a directory is no file either."""
    _refused(Path("/dev/zero"), "not a regular file")
    _refused(tmp_path, "not a regular file")


@pytest.mark.parametrize(("path", "match"), [("cal\x00.yaml", "null byte"), (12.5, "must be a path")])
def test_bad_paths_are_refused(path: Any, match: str) -> None:
    """A NUL in the path (a ValueError of the OS layer) or no path at all: CalibrationFileError."""
    with pytest.raises(CalibrationFileError, match=match):
        load_calibrations(path)


# -- saving: killed saves leave no lasting debris, the rename is made durable ---------------------------------------


def _dead_pid() -> int:
    """The pid of a process that has exited (a child, waited for)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_stale_temp_files_are_removed_by_the_next_save(tmp_path: Path, two_sensors: dict[str, Calibration]) -> None:
    """Temp files of killed saves of the same target go (dead process, or older than a minute); others stay."""
    target = tmp_path / "cal.yaml"
    of_dead = tmp_path / f".cal.yaml.{_dead_pid()}.k2j4x_a1.tmp"
    old = tmp_path / ".cal.yaml.q8w_9zz1.tmp"  # the name before pids were added, an hour old
    running = tmp_path / f".cal.yaml.{os.getppid()}.abcdefgh.tmp"  # a live process's save in progress
    other = tmp_path / f".other.yaml.{_dead_pid()}.abcdefgh.tmp"  # another target's
    for p in (of_dead, old, running, other):
        p.write_text("margcal:\n  ros__parameters:\n")
    os.utime(old, (1.0e9, 1.0e9))
    save_calibrations(target, two_sensors)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["cal.yaml", running.name, other.name])
    assert load_calibrations(target)["mag"].allclose(two_sensors["mag"], rtol=0)


def test_save_fsyncs_the_folder_after_the_rename(
    tmp_path: Path, two_sensors: dict[str, Calibration], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The file is fsynced before the rename and the folder after it, so the new name survives a power cut."""
    synced: list[str] = []
    real_fsync = os.fsync

    def spy(fd: int) -> None:
        synced.append("dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    save_calibrations(tmp_path / "cal.yaml", two_sensors)
    assert synced == ["file", "dir"]
