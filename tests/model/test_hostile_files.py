"""Saving a calibration file over what is not a plain file (issue 26, item 23).

A ``calibration_file`` that is a symbolic link (to a file on a persistent volume) keeps its link and
its target gets the new calibration; a FIFO, a device, a directory, a link loop or a link into a
missing folder is refused before anything is written, never replaced by a regular file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import load_calibrations, save_calibrations
from ros_margcal.model.errors import CalibrationFileError

needs_symlinks = pytest.mark.skipif(not hasattr(os, "symlink") or os.name != "posix", reason="POSIX links only")


def _cal(norm: float) -> dict[str, Calibration]:
    return {"mag": Calibration(np.array([1e-6, 2e-6, -3e-6]), np.eye(3), norm, sensor="mag", unit="T")}


def _debris(*folders: Path) -> list[str]:
    """Temporary files a save left behind."""
    return [p.name for f in folders for p in f.iterdir() if p.name.endswith(".tmp")]


@needs_symlinks
@pytest.mark.parametrize("relative", [False, True])
def test_a_link_survives_and_its_target_gets_the_calibration(tmp_path: Path, relative: bool) -> None:
    """Saving over a link to a file on another volume writes the file it points to; the link stays a link."""
    volume, config = tmp_path / "persistent", tmp_path / "config"
    volume.mkdir()
    config.mkdir()
    real = save_calibrations(volume / "cal.yaml", _cal(5.0e-5))
    link = config / "cal.yaml"
    link.symlink_to(os.path.relpath(real, config) if relative else real)
    assert save_calibrations(link, _cal(4.0e-5)) == link
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert load_calibrations(real)["mag"].norm == 4.0e-5
    assert stat.S_ISREG(real.lstat().st_mode)
    assert _debris(volume, config) == []


@needs_symlinks
def test_a_chain_of_links_and_a_dangling_link_are_followed(tmp_path: Path) -> None:
    """A link to a link to the file is followed to its end; a link whose target does not exist yet creates it."""
    real = save_calibrations(tmp_path / "real.yaml", _cal(5.0e-5))
    (tmp_path / "b.yaml").symlink_to("real.yaml")
    (tmp_path / "a.yaml").symlink_to("b.yaml")
    save_calibrations(tmp_path / "a.yaml", _cal(4.5e-5))
    assert (tmp_path / "a.yaml").is_symlink() and (tmp_path / "b.yaml").is_symlink()
    assert load_calibrations(real)["mag"].norm == 4.5e-5
    (tmp_path / "vol").mkdir()
    dangling = tmp_path / "new.yaml"
    dangling.symlink_to(tmp_path / "vol" / "first.yaml")
    save_calibrations(dangling, _cal(4.2e-5))
    assert dangling.is_symlink() and load_calibrations(tmp_path / "vol" / "first.yaml")["mag"].norm == 4.2e-5


def _refused(path: Path, match: str) -> None:
    """The save is refused with a one-line CalibrationFileError that is also an OSError (the node catches OSError)."""
    with pytest.raises(CalibrationFileError, match=match) as info:
        save_calibrations(path, _cal(4.0e-5))
    assert isinstance(info.value, OSError)
    assert "\n" not in str(info.value) and "cannot save calibration file" in str(info.value)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_is_refused_and_kept(tmp_path: Path) -> None:
    """A FIFO at the path is not replaced by a regular file: the save is refused and the FIFO stays."""
    fifo = tmp_path / "cal.yaml"
    os.mkfifo(fifo)
    _refused(fifo, "it is a FIFO, not a regular file")
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    assert _debris(tmp_path) == []


@needs_symlinks
def test_a_link_to_a_device_is_refused_and_kept(tmp_path: Path) -> None:
    """A link to /dev/null is refused (not replaced by a regular file); the message names the link's target."""
    if not Path("/dev/null").exists():
        pytest.skip("no /dev/null")
    link = tmp_path / "cal.yaml"
    link.symlink_to("/dev/null")
    _refused(link, r"\(a link to /dev/null\): it is a character device")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"
    assert _debris(tmp_path) == []


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="mknod of a device needs root")
def test_a_device_node_is_refused_as_root(tmp_path: Path) -> None:
    """As root a device node at the path could be replaced: it is refused and stays a device."""
    dev = tmp_path / "cal.yaml"
    os.mknod(dev, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    _refused(dev, "character device")
    assert stat.S_ISCHR(dev.lstat().st_mode)


@needs_symlinks
def test_a_directory_a_loop_and_a_link_into_a_missing_folder_are_refused(tmp_path: Path) -> None:
    """Each is refused with a message that says what the path is; nothing is created."""
    (tmp_path / "dir.yaml").mkdir()
    _refused(tmp_path / "dir.yaml", "it is a directory")
    (tmp_path / "loop_a").symlink_to("loop_b")
    (tmp_path / "loop_b").symlink_to("loop_a")
    _refused(tmp_path / "loop_a", "loop of symbolic links")
    (tmp_path / "unmounted").symlink_to(tmp_path / "mnt" / "volume" / "cal.yaml")
    _refused(tmp_path / "unmounted", "does not exist")
    assert not (tmp_path / "mnt").exists()
    assert _debris(tmp_path) == []


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_margcal_calibrate_refuses_a_fifo_output_on_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``margcal calibrate -o FIFO`` exits 2 with a one-line error, the FIFO left in place."""
    from ros_margcal.cli import main
    from ros_margcal.recordings.csvfile import write_csv
    from ros_margcal.sim.simulation import magnetometer_stream, random_sensor

    rng = np.random.default_rng(5)
    rec = magnetometer_stream(random_sensor(rng, "mag", model="diag"), 20.0, 20.0, rng, noise=0.005)
    csv = write_csv(tmp_path / "m_mag.csv", rec)
    fifo = tmp_path / "out.yaml"
    os.mkfifo(fifo)
    assert main(["calibrate", str(csv), "--sensor", "mag", "--unit", "T", "-o", str(fifo)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "FIFO" in err[0], err
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
