"""``margcal diagnose`` on hostile input (issue 26, items 16-19).

Bad options are refused up front (16); a static recording is ``unexplained`` because it is static (17);
an interrupt while the report is written leaves the previous pair of files (18); a recording whose clock
restarts is diagnosed in file order (19). One smooth turn holds no offset change (issue 25); a step during
repeated turns still does.
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ros_margcal.diagnosis import check_options, diagnose, summary, write_report
from ros_margcal.diagnosis import report as report_module
from ros_margcal.diagnosis.changes import locate_offset_change, sectors
from ros_margcal.diagnosis.inputs import file_order_times
from ros_margcal.diagnosis.twin_fits import static_reason
from ros_margcal.model.errors import ConfigError
from ros_margcal.recordings.csvfile import write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import magnetometer_stream, random_sensor


def _stream(seed: int = 3, duration: float = 30.0, noise: float = 0.005) -> Recording:
    rng = np.random.default_rng([seed, 7])
    return magnetometer_stream(random_sensor(rng, "mag", model="diag"), duration, 50.0, rng, noise=noise)


def _static(n: int = 3000, seed: int = 1, lsb: float | None = None) -> Recording:
    """A magnetometer that never moved: one reading (tesla) plus white noise, optionally quantised."""
    rng = np.random.default_rng(seed)
    raw = np.array([20e-6, -5e-6, 40e-6]) + 0.3e-6 * rng.standard_normal((n, 3))
    if lsb is not None:
        raw = np.round(raw / lsb) * lsb
    return Recording(t=np.arange(n) * 0.02, raw=raw, sensor="mag", unit="T")


# -- 16: options are checked before any work --------------------------------------------------------------------


BAD_OPTIONS = [
    (["--norm=-1"], "--norm must be a positive finite number"),
    (["--norm=0"], "--norm must be a positive finite number"),
    (["--norm=nan"], "--norm must be a positive finite number"),
    (["--norm=inf"], "--norm must be a positive finite number"),
    (["--holdout=2"], r"--holdout must be a fraction in \[0.1, 0.9\]"),
    (["--holdout=nan"], r"--holdout must be a fraction in \[0.1, 0.9\]"),
    (["--retrain-sets=-5"], "--retrain-sets must be an integer of at least 2"),
    (["--retrain-sets=0"], "--retrain-sets must be an integer of at least 2"),
    (["--rest-noise=-1e-7"], "--rest-noise must be a non-negative finite std"),
    (["--shape-tolerance=nan"], "--shape-tolerance must be a non-negative finite fraction"),
    (["--n-fit=10"], "--n-fit must be an integer of at least 100"),
]


@pytest.mark.parametrize(("option", "match"), BAD_OPTIONS)
def test_bad_options_exit_2_before_the_diagnosis(option: list[str], match: str, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Each bad option exits 2 with a one-line error naming it; nothing is read, diagnosed or written."""
    import re

    from ros_margcal.cli import diagnose as cli_diagnose
    from ros_margcal.cli import main

    def ran(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the diagnosis ran despite a bad option")

    monkeypatch.setattr(cli_diagnose, "diagnose", ran)
    csv = write_csv(tmp_path / "m_mag.csv", _stream(duration=5.0))
    out = tmp_path / "out"
    assert main(["diagnose", str(csv), "--sensor", "mag", "--out", str(out), *option]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("margcal diagnose: error: "), err
    assert re.search(match, err[0]), err[0]
    assert not out.exists()


def test_bad_options_are_config_errors_of_the_library() -> None:
    """``diagnose`` itself refuses a bad norm instead of turning the fit's refusal into an unexplained verdict."""
    rec = _stream(duration=5.0)
    for kwargs in ({"norm": -1.0}, {"norm": float("nan")}, {"rest_noise": -1.0}, {"shape_tolerance": float("inf")},
                   {"n_fit": 5}):
        with pytest.raises(ConfigError, match=next(iter(kwargs))):
            diagnose(rec, sensor="mag", **kwargs)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="n_sets"):
        check_options(n_sets=1)
    check_options(norm=1.0, rest_noise=0.0, n_fit=100, shape_tolerance=0.0, split=0.5, n_sets=2)  # the edges pass


# -- 17: a static recording is unexplained, because it is static --------------------------------------------------


@pytest.mark.parametrize("lsb", [None, 0.5e-6], ids=["white", "quantised"])
def test_a_static_recording_is_unexplained_as_static(lsb: float | None, tmp_path: Path) -> None:
    """The sensor never moved: no confident cause, ``unexplained`` with a reason a user understands (and a
    quantised one whose readings flip between two levels is not taken for clipping)."""
    d = diagnose(_static(lsb=lsb), sensor="mag", quick=True)
    assert d.cause == "unexplained" and d.effects == []
    assert d.reason.startswith("static: the sensor did not move"), d.reason
    assert "--rest-recording" in d.reason
    jpath, hpath = write_report(d, tmp_path)
    assert json.loads(jpath.read_text())["reason"] == d.reason and hpath.is_file()
    assert "cause: unexplained (static: the sensor did not move" in summary(d)


def test_one_reading_throughout_is_static_not_clipped() -> None:
    """Every reading the same value (a stuck or static logger): static, not 'saturation' because each axis sits
    at its extreme reading (its spread, 1e-19 T of rounding, was above its noise, 0: not static, and the fits then
    refused the identical points)."""
    rec = Recording(t=np.arange(3000) * 0.02, raw=np.tile([3e-5, 1e-5, -4e-5], (3000, 1)), sensor="mag", unit="T")
    d = diagnose(rec, sensor="mag", quick=True)
    assert d.cause == "unexplained" and d.cause_effects == [], (d.cause, d.reason)
    assert d.reason.startswith("static: the sensor did not move (its readings are one value"), d.reason


@pytest.mark.parametrize("name", ["sunsided_hmc5883l_static_10min_mag.csv",
                                  "sunsided_mpu6050_unmoved-with-x-pointing-forward_acc.csv"])
def test_real_static_recordings_are_static(name: str, real_recording: Any) -> None:
    """The real static logs (an HMC5883L for 10 min, an MPU6050 unmoved) are static."""
    from ros_margcal.recordings.read import read_recording

    d = diagnose(read_recording(real_recording(name)), quick=True)
    assert d.cause == "unexplained" and d.reason.startswith("static:"), d.reason


def test_static_reason_leaves_moving_and_shuffled_recordings_alone() -> None:
    """A turning sensor is not static, in time order or shuffled (out of order, second differences see the motion)."""
    rec = _stream()
    assert static_reason(rec.raw) == ""
    assert static_reason(rec.raw[np.random.default_rng(0).permutation(len(rec.raw))]) == ""
    assert static_reason(_static().raw).startswith("static:")
    assert static_reason(np.tile([1.0, 2.0, 3.0], (100, 1))).startswith("static:")  # no noise at all


# -- 18: an interrupt while the report is written leaves the previous pair -----------------------------------------


def _quick_diagnosis(n: int) -> Any:
    """A diagnosis made at once: a recording too short for a twin (its n_samples tells the runs apart)."""
    return diagnose(Recording(t=np.arange(n) * 0.01, raw=np.ones((n, 3)), sensor="mag"), sensor="mag")


def _pair(out: Path) -> tuple[int, str]:
    return json.loads((out / "diagnosis.json").read_text())["n_samples"], (out / "report.html").read_text()


def _debris(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.name not in ("diagnosis.json", "report.html"))


def test_an_interrupt_while_the_report_is_rendered_leaves_the_old_pair(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while the HTML is made (after the JSON was ready) leaves the previous run's json and html."""
    write_report(_quick_diagnosis(10), tmp_path)
    old = _pair(tmp_path)
    assert old[0] == 10

    def interrupted(diag: Any) -> str:
        raise KeyboardInterrupt

    monkeypatch.setattr(report_module, "summary", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_report(_quick_diagnosis(12), tmp_path)
    assert _pair(tmp_path) == old
    assert _debris(tmp_path) == []


def test_an_interrupt_while_the_files_are_written_leaves_the_old_pair(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while the second file is written (the first one done) leaves both old files and no temporary file."""
    write_report(_quick_diagnosis(10), tmp_path)
    old = _pair(tmp_path)
    real = report_module.write_temp
    calls: list[Path] = []

    def second_interrupted(target: Path, text: str) -> Path:
        calls.append(target)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(target, text)

    monkeypatch.setattr(report_module, "write_temp", second_interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_report(_quick_diagnosis(12), tmp_path)
    assert len(calls) == 2
    assert _pair(tmp_path) == old
    assert _debris(tmp_path) == []


@pytest.mark.skipif(not hasattr(os, "kill") or os.name != "posix", reason="POSIX signals only")
def test_ctrl_c_between_the_renames_is_held_until_both_are_new(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT arriving as the first file is renamed is raised only after the second: both files are new."""
    write_report(_quick_diagnosis(10), tmp_path)
    real = os.replace
    sent: list[int] = []

    def replace_then_ctrl_c(src: Any, dst: Any) -> None:
        real(src, dst)
        if not sent:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(report_module.os, "replace", replace_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        write_report(_quick_diagnosis(12), tmp_path)
    monkeypatch.undo()
    n, html = _pair(tmp_path)
    assert sent and n == 12 and "12 samples" in html
    assert _debris(tmp_path) == []


# -- 19: a clock that restarts ------------------------------------------------------------------------------------


def test_file_order_times_continue_each_part_after_the_one_before() -> None:
    """Two restarts: each part starts one median interval after the part before; a clean clock is left as it is."""
    t = np.array([100.0, 100.1, 100.2, 0.0, 0.1, 0.2, 0.3, 0.05, 0.15])
    out, restarts = file_order_times(t)
    assert restarts == [2, 6]
    assert np.all(np.diff(out) > 0)
    np.testing.assert_allclose(out, 100.0 + 0.1 * np.arange(9), atol=1e-9)
    same = np.arange(5.0)
    assert file_order_times(same)[0] is same and file_order_times(same)[1] == []


def test_a_clock_jumping_ahead_by_years_is_continued_like_a_restart() -> None:
    """A stamp jump of 1e12 s (a far-future clock) is taken as a restart, not as a pause the twin must simulate (it
    asked for a 7 TiB array); a pause of an hour stays as it is."""
    t = np.r_[0.1 * np.arange(5), 1e12 + 0.1 * np.arange(5)]
    out, restarts = file_order_times(t)
    assert restarts == [4]
    np.testing.assert_allclose(out, 0.1 * np.arange(10), atol=1e-3)  # 1e12 s stamps hold 0.1 ms steps to 1e-4
    paused = np.r_[0.1 * np.arange(5), 3600.0 + 0.1 * np.arange(5)]
    assert file_order_times(paused)[1] == []


def test_one_far_future_stamp_leaves_the_times_in_order() -> None:
    """One glitched stamp (1e30 s) between clean ones: every part continues the one before, the times stay finite,
    ordered and 0.1 s apart (adding the 1e30 s shift to the stamps after it rounded them all to one value)."""
    t = 0.1 * np.arange(10)
    t[4] = 1e30
    out, restarts = file_order_times(t)
    assert restarts == [3, 4]
    np.testing.assert_allclose(out, 0.1 * np.arange(10), atol=1e-9)


def test_a_recording_with_one_far_future_stamp_is_diagnosed() -> None:
    """The fuzzed CSV: one stamp of 1e30 s halfway; diagnosed in file order (it was 'unexplained: t must be finite
    and non-decreasing' after the times were said to be continued)."""
    rec = _stream(duration=20.0)
    half = len(rec.t) // 2
    rec.t = rec.t.copy()
    rec.t[half] = 1e30
    d = diagnose(rec, sensor="mag", quick=True)
    assert d.time_restarts == [half - 1, half]
    assert "non-decreasing" not in d.reason and d.twin is not None, d.reason
    assert np.all(np.diff(d.twin.t) >= 0) and float(d.twin.t[-1] - d.twin.t[0]) < 30.0


def test_a_recording_whose_clock_jumps_by_years_is_diagnosed() -> None:
    """The fuzzed case: a 1e12 s jump halfway through a stream is diagnosed (it raised an allocation error)."""
    rec = _stream(duration=20.0)
    half = len(rec.t) // 2
    rec.t = np.r_[rec.t[:half], rec.t[half:] + 1e12]
    d = diagnose(rec, sensor="mag", quick=True)
    assert d.time_restarts == [half - 1] and d.twin is not None
    assert float(d.twin.t[-1] - d.twin.t[0]) < 30.0


def test_a_recording_whose_clock_restarts_is_diagnosed_in_file_order(tmp_path: Path) -> None:
    """A logger reboot halfway (stamps back to ~0): the diagnosis runs on the samples in file order, says so,
    and gives the verdict of a clean recording (not 'unexplained' because t decreases)."""
    rec = _stream(duration=20.0)
    half = len(rec.t) // 2
    rec.t = np.concatenate([rec.t[:half] + 1000.0, rec.t[half:] - rec.t[half] + 0.01])
    d = diagnose(rec, sensor="mag", quick=True)
    assert d.time_restarts == [half - 1]
    assert "non-decreasing" not in d.reason and d.cause != "unexplained", (d.cause, d.reason)
    assert d.twin is not None and np.all(np.diff(d.twin.t) >= 0)
    assert "the clock goes back (or jumps ahead by more than a day) 1 time" in summary(d)
    jpath, _ = write_report(d, tmp_path)
    assert json.loads(jpath.read_text())["time_restarts"] == [half - 1]


def test_cli_on_a_restarted_clock_never_advises_an_option_it_lacks(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """``margcal diagnose`` on a CSV whose clock restarts: it runs (the reader gives the samples in file order),
    or it exits 2 on one line saying what to do, never advising ``sort=True``, which diagnose has no option for."""
    from ros_margcal.cli import diagnose as cli_diagnose
    from ros_margcal.cli import main

    seen: dict[str, Any] = {}

    def fake(rec: Any, **kwargs: Any) -> Any:  # the diagnosis itself is tested above: record what it was given
        seen["t"] = np.asarray(rec.t)
        return _quick_diagnosis(10)

    monkeypatch.setattr(cli_diagnose, "diagnose", fake)
    rec = _stream(duration=10.0)
    half = len(rec.t) // 2
    rec.t = np.concatenate([rec.t[:half] + 1000.0, rec.t[half:] - rec.t[half] + 0.01])
    csv = write_csv(tmp_path / "reboot_mag.csv", rec)
    code = main(["diagnose", str(csv), "--out", str(tmp_path / "d"), "--no-validator"])
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:  # a reader that keeps file order: the samples reach the diagnosis unsorted
        np.testing.assert_array_equal(seen["t"], rec.t)
    else:
        assert code == 2 and len(err) == 1, err
        assert "sort=True" not in err[0] and "split it where the time goes back" in err[0], err[0]
        assert "after sample" in err[0]


# -- issue 25: one smooth turn is no offset change ------------------------------------------------------------------


def _turn(seed: int, turns: float, step: float = 0.0, tilt_deg: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle turning smoothly (yaw from 0 to ``turns`` x 360 degrees, easing in and out, 3 s still at each end)
    with +-``tilt_deg`` of roll and pitch, in a 48 µT field at 60 degrees inclination; soft iron within 5 %, hard iron
    N(0, 20 µT), 0.1 µT noise, 50 Hz; ``step`` field norms of hard iron added half way."""
    rng = np.random.default_rng([seed, 25])
    t = np.arange(0.0, 20.0 * turns + 6.0, 0.02)
    s = np.clip((t - 3.0) / (20.0 * turns), 0.0, 1.0)
    yaw = 2 * np.pi * turns * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
    roll = np.radians(tilt_deg) * np.sin(2 * np.pi * t / 7.0)
    pitch = np.radians(tilt_deg) * np.sin(2 * np.pi * t / 11.0 + 1.0)
    inc = np.radians(60.0)
    field = 48.0 * np.array([np.cos(inc), 0.0, -np.sin(inc)])
    cy, sy, cr, sr, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    # body = (Rz(yaw) Ry(pitch) Rx(roll))^T world
    hx, hy, hz = field
    x1, y1 = cy * hx + sy * hy, -sy * hx + cy * hy
    x2, z2 = cp * x1 - sp * hz, sp * x1 + cp * hz
    y3, z3 = cr * y1 + sr * z2, -sr * y1 + cr * z2
    body = np.column_stack([x2, y3, z3])
    soft = np.eye(3) + rng.uniform(-0.05, 0.05, (3, 3))
    raw = body @ soft.T + rng.normal(scale=20.0, size=3)
    if step:
        raw[t > t[-1] / 2] += step * 48.0 * np.array([0.8, 0.5, -0.33])
    return t, raw + rng.normal(scale=0.1, size=raw.shape)


@pytest.mark.parametrize("seed", range(4))
def test_one_smooth_turn_declares_no_offset_change(seed: int) -> None:
    """A car's single circle split in two leaves two arcs that fit better apart (one shape with two centres removed
    0.50-0.67 of the residual: "offset changed by 195 % of the field"); neither half goes round, so no change."""
    t, raw = _turn(seed, 1.0)
    assert locate_offset_change(t, raw, min_shared_drop=0.5) is None
    found = locate_offset_change(t, raw, min_shared_drop=0.5, min_sectors=0)  # the old rule fires: the arcs' split
    assert found is not None and found.relative_step > 0.2 and found.sectors <= 10
    half = raw[: len(raw) // 2]
    assert sectors(half) <= 10


@pytest.mark.parametrize("seed", range(2))
def test_a_step_during_repeated_turns_is_still_located(seed: int) -> None:
    """Three turns with a hard-iron step of 0.3 field norms half way: located within 1 s of the step."""
    t, raw = _turn(seed, 3.0, step=0.3)
    found = locate_offset_change(t, raw, min_shared_drop=0.5)
    assert found is not None and abs(found.t - t[-1] / 2) < 1.0
    assert found.sectors >= 11


def test_calibrate_on_one_smooth_turn_reports_no_change(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``margcal calibrate`` on the single turn: no "offset changed" in its diagnosis."""
    from ros_margcal.cli import main

    t, raw = _turn(0, 1.0)
    path = write_csv(tmp_path / "turn_mag.csv", Recording(t=t, raw=raw, sensor="mag"))
    main(["calibrate", str(path), "--unit", "uT"])
    out = capsys.readouterr().out
    assert "offset changed" not in out and "requested fit" in out
