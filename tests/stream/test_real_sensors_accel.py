"""Real-sensor accelerometers in the stream: a noisy MEMS part, raw unsigned ADC counts, the shared recordings."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from ros_margcal.cli import main
from ros_margcal.cli.calibrate_guard import EXIT_REFUSED
from ros_margcal.coverage.gate import InactivityGate
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import load_calibrations
from ros_margcal.recordings.read import read_recording
from ros_margcal.stream.calibrator import SensorCalibrator, State
from ros_margcal.stream.config import PipelineConfig, plausibility
from ros_margcal.stream.intake import Intake
from ros_margcal.stream.replay import replay

G = 9.80665
RATE = 100.0


def _poses(rng: np.random.Generator, n_poses: int, rest_s: float = 4.0, move_s: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """Times and true specific force (in g) of a body held in ``n_poses`` random poses, turned smoothly between."""
    rots = Rotation.random(n_poses, random_state=rng.integers(1 << 31))
    t, f = [], []
    t0 = 0.0
    for k in range(n_poses):
        n_rest = int(rest_s * RATE)
        t.append(t0 + np.arange(n_rest) / RATE)
        f.append(np.tile(rots[k].inv().apply([0.0, 0.0, 1.0]), (n_rest, 1)))
        t0 += n_rest / RATE
        if k + 1 < n_poses:
            n_move = int(move_s * RATE)
            s = np.arange(n_move) / n_move
            ease = 0.5 - 0.5 * np.cos(np.pi * s)  # starts and ends at rest
            turn = Slerp([0.0, 1.0], Rotation.concatenate([rots[k], rots[k + 1]]))(ease)
            hand = 0.05 * np.sin(2 * np.pi * s)[:, None] * rng.normal(size=3)  # the hand's own push, g
            t.append(t0 + np.arange(n_move) / RATE)
            f.append(turn.inv().apply([0.0, 0.0, 1.0]) + hand)
            t0 += n_move / RATE
    return np.concatenate(t), np.concatenate(f)


def _mems(rng: np.random.Generator, noise_g: float = 6e-3) -> tuple[np.ndarray, np.ndarray, Calibration]:
    """A MEMS accelerometer at 2x Gietzelt's noise (6e-3 g white per axis, 100 Hz), gain errors of a few %, 0.05 g
    bias, 16 poses: its times, raw readings in g and the truth (h = W (raw - b))."""
    t, f = _poses(rng, 16)
    gains = np.diag([1.03, 0.97, 1.02])
    cross = np.array([[0.0, 0.01, -0.005], [0.01, 0.0, 0.008], [-0.005, 0.008, 0.0]])
    k = gains + cross  # raw = K h + b
    bias = np.array([0.05, -0.03, 0.04])
    raw = f @ k.T + bias + rng.normal(scale=noise_g, size=f.shape)
    return t, raw, Calibration(bias, np.linalg.inv(k), norm=1.0, sensor="accel", unit="g")


def _run(cal: SensorCalibrator, t: np.ndarray, raw: np.ndarray) -> float | None:
    """Feed the stream; the time of the first calibration (None if none)."""
    first = None
    for ti, v in zip(t, raw, strict=True):
        cal.push(float(ti), v)
        if first is None and cal.calibration is not None:
            first = float(ti)
    return first


def test_a_mems_accelerometer_at_twice_gietzelts_noise_calibrates_from_still_poses() -> None:
    """6e-3 g per axis (Gietzelt's CV 3e-3 x 2): the gate learns the rest noise, finds the poses, the fit is right."""
    t, raw, truth = _mems(np.random.default_rng(61))
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g"))
    first = _run(cal, t, raw)
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert first is not None and first < t[-1]
    fitted = cal.calibration
    assert fitted is not None
    assert np.linalg.norm(fitted.offset - truth.offset) < 0.01, fitted.offset  # g
    cv, axis = cal._gate.thresholds
    assert 3e-3 < axis <= 1e-2 and cv <= 1e-2  # widened, within the cap
    # a still pose's calibrated norm is 1 g within the noise of a window mean
    check = cal.calibration.apply(truth.inverse_apply(np.eye(3)))
    assert np.abs(np.linalg.norm(check, axis=1) - 1.0).max() < 5e-3


def test_the_gate_learns_but_still_refuses_a_move() -> None:
    """The learnt gate emits nothing during the moves of the MEMS stream: every emitted mean is a pose's."""
    t, raw, truth = _mems(np.random.default_rng(62))
    gate = InactivityGate(learn=True)
    out = [e for e in (gate.push(ti, v) for ti, v in zip(t, raw, strict=True)) if e is not None]
    assert len(out) >= 14
    norms = np.linalg.norm(truth.apply(np.array(out)), axis=1)
    assert np.abs(norms - 1.0).max() < 5e-3, norms  # a mean over a move would be off by the hand's push


def test_raw_unsigned_counts_calibrate() -> None:
    """An unsigned 16-bit ADC (mid-scale 32768, 1 g = 16384 counts): the offset guard in counts lets it through."""
    rng = np.random.default_rng(63)
    t, f = _poses(rng, 16)
    k = np.diag([16384 * 1.02, 16384 * 0.98, 16384 * 1.01])
    raw = f @ k.T + np.array([32768.0, 32768.0 + 300.0, 32768.0 - 200.0]) + rng.normal(scale=40.0, size=f.shape)
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "counts"))
    _run(cal, t, raw)
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert cal.calibration is not None
    assert np.allclose(cal.calibration.offset, [32768.0, 33068.0, 32568.0], atol=50.0)


def test_an_accelerometer_offset_is_refused_in_its_own_words() -> None:
    """The accelerometer's offset guard speaks of bias and gravity norms, never of hard iron, and says how to raise it."""
    cfg = PipelineConfig.for_sensor("accel", "g")
    why = plausibility(Calibration(np.array([0.5, 0.0, 0.0]), np.eye(3), norm=1.0, sensor="accel", unit="g"), cfg)
    assert "bias" in why and "gravity norms" in why and "hard iron" not in why
    assert "--set max_offset_ratio=" in why and "accel.max_offset_ratio" in why
    assert "0.5 gravity norms" in why


def test_the_uncertainty_message_shows_enough_digits() -> None:
    """"std of b_x is 1 % > 1 %" cannot happen: three significant digits on both sides."""
    cfg = PipelineConfig.for_sensor("mag", "uT", max_parameter_std=0.0104)
    cal = Calibration(np.zeros(3), np.eye(3), norm=50.0, sensor="mag", unit="uT", parameter_names=("b_x",),
                      covariance=np.array([[(0.0106 * 50.0) ** 2]]))  # b_x std 1.06 % of the radius
    why = plausibility(cal, cfg)
    assert "std of b_x is 1.06 % > 1.04 %" in why, why


def _held(rng: np.random.Generator, ups: list[tuple[float, float, float]], rest_s: float = 3.5) -> tuple[np.ndarray, np.ndarray]:
    """Times and raw readings (g; the MEMS part of ``_mems``, 4e-3 g noise) of a body held still with each of ``ups``
    (body axes, not normalised) pointing up in turn for ``rest_s``, a 1 s swing between."""
    gains = np.diag([1.03, 0.97, 1.02]) + np.array([[0.0, 0.01, -0.005], [0.01, 0.0, 0.008], [-0.005, 0.008, 0.0]])
    f = []
    for k, up in enumerate(ups):
        u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        f.append(np.tile(u, (int(rest_s * RATE), 1)))
        if k + 1 < len(ups):
            f.append(rng.normal(scale=0.4, size=(int(RATE), 3)) + u)  # the hand turning it: no rest
    force = np.concatenate(f)
    raw = force @ gains.T + np.array([0.05, -0.03, 0.04]) + rng.normal(scale=4e-3, size=force.shape)
    return np.arange(len(raw)) / RATE, raw


def test_poses_that_leave_a_cross_term_loose_say_which_pose_is_missing(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Ten poses as a real MPU-6050 procedure held them (each axis up and down, four tilted between y or x and z, none
    between x and y): stream and batch both say that w_xy is loose and that a pose between x and y is missing (the
    stream said "none need more poses": each parameter's std had halved from the prior's, w_xy's to 3-4 %)."""
    ups = [(0, 0, 1), (0, 0, -1), (-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 1, 1), (0, -1, 1), (-1, 0, 1),
           (1, 0, 1)]
    t, raw = _held(np.random.default_rng(62), ups, rest_s=5.0)
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g"))
    _run(cal, t, raw)
    msg = cal.status().message
    assert cal.calibration is None, msg
    determined, loose = msg.split("the poses seen determine ")[1].split("; ")[:2]
    assert "w_xy" not in determined and loose.startswith("w_xy needs more poses"), msg
    assert "between the x and y axes" in loose, msg
    csv = tmp_path / "poses_acc.csv"
    np.savetxt(csv, np.column_stack([t, raw]), delimiter=",", header="t,x,y,z", comments="")
    code = main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "-o", str(tmp_path / "out.yaml")])
    err = capsys.readouterr().err
    assert code == EXIT_REFUSED and not (tmp_path / "out.yaml").exists(), err
    assert "std of w_xy" in err and "between the x and y axes" in err, err


def test_calibrate_names_holds_shorter_than_the_gate_window(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Twelve poses held 1.2 s each (a pose log logged faster than its holds were timed for: the LSM9DS1's at 100 Hz):
    no 2 s window is still, and calibrate asked "was it moving all through?" and for a CV threshold that found nothing;
    it now names the short holds and the window that finds them, which calibrates."""
    ups = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (1, 1, 0), (1, 0, 1), (0, 1, 1),
           (-1, -1, 1), (1, -1, -1), (-1, 1, -1)]
    t, raw = _held(np.random.default_rng(9), ups, rest_s=1.2)
    csv = tmp_path / "short_acc.csv"
    np.savetxt(csv, np.column_stack([t, raw]), delimiter=",", header="t,x,y,z", comments="")
    assert main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g"]) == 2
    err = capsys.readouterr().err
    assert "hold each pose for 2 s or more, or --set accel.gate_window_s=1 " in err and "moving all through" not in err, err
    assert main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "--set", "accel.gate_window_s=1"]) == 0


def test_poses_about_one_axis_are_not_called_a_magnetometer_on_its_side() -> None:
    """An accelerometer turned through poses about its x axis first (the LSM9DS1 pose log's first two minutes) was
    told "the readings trace a ring about the magnetometer's x axis ... set accel.up_axis=x", an option the
    accelerometer refuses: the hint is the magnetometer's alone; the poses it needs are named instead."""
    ups = [(0, 0, 1), (0, 1, 1), (0, 1, 0), (0, 1, -1), (0, 0, -1), (0, -1, -1), (0, -1, 0), (0, -1, 1)]
    t, raw = _held(np.random.default_rng(63), ups, rest_s=5.0)
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g"))
    _run(cal, t, raw)
    msg = cal.status().message
    assert "partial fit (not published for the accel)" in msg and "poses with x pointing up and down" in msg, msg
    assert "up_axis" not in msg and "magnetometer" not in msg, msg


@pytest.mark.parametrize("model", ["sym", "diag"])
def test_calibrate_makes_an_accelerometer_read_gravity_as_the_stream_does(tmp_path: Path, model: str) -> None:
    """Twelve poses of a part whose gains average 1.0067: ``calibrate`` fitted the norm too, which took that mean
    scale (1.00637 g) and left W's mean diagonal at 1, so the written calibration read 1.006 g at rest; gravity is
    now fixed as in the stream, and W undoes the gains."""
    ups = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (1, 1, 0), (1, 0, 1), (0, 1, 1),
           (-1, -1, 1), (1, -1, -1), (-1, 1, -1)]
    t, raw = _held(np.random.default_rng(5), ups, rest_s=5.0)
    csv, out = tmp_path / "poses_acc.csv", tmp_path / "out.yaml"
    np.savetxt(csv, np.column_stack([t, raw]), delimiter=",", header="t,x,y,z", comments="")
    assert main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "--model", model, "-o", str(out)]) == 0
    cal = load_calibrations(out)["accel"]
    assert cal.norm == 1.0
    np.testing.assert_allclose(np.diag(cal.matrix), 1.0 / np.array([1.03, 0.97, 1.02]), atol=3e-3)
    still = raw[: int(5.0 * RATE)]  # the first pose, z up
    assert abs(float(np.median(np.linalg.norm(cal.apply(still), axis=1))) - 1.0) < 2e-3


def test_the_partial_coverage_line_of_calibrate_agrees_with_its_guard_rails(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """A pose barely off the x axis toward y narrows w_xy from the prior's without determining it (a real rocket
    IMU's twelve poses: 1.7 %): ``calibrate`` said "the directions determine ... w_xy" and then refused for w_xy's
    std; now it names w_xy narrowed, not determined, by the guard rails' 1 %."""
    ups = [(0, 0, 1), (0, 0, -1), (-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 1, 1), (0, -1, 1), (-1, 0, 1),
           (1, 0, 1), (1, 0.01, 0.3)]
    t, raw = _held(np.random.default_rng(62), ups, rest_s=5.0)
    csv = tmp_path / "poses_acc.csv"
    np.savetxt(csv, np.column_stack([t, raw]), delimiter=",", header="t,x,y,z", comments="")
    code = main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "-o", str(tmp_path / "out.yaml")])
    out, err = capsys.readouterr()
    assert code == EXIT_REFUSED and "std of w_xy" in err, err
    coverage = next(line for line in (out + err).splitlines() if line.startswith("partial coverage:"))
    determined = coverage.split(" (std <= 1 %)")[0]
    assert "w_xy" not in determined and "w_yz" in determined, coverage
    assert "narrow w_xy without determining it; none kept from the broad prior" in coverage, coverage


def test_a_still_sensor_noisier_than_the_gate_learns_is_told_the_threshold_that_finds_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One pose, 60 s at 10 Hz, 1.2 % noise per axis quantised to 0.01 g (a real MPU-6050 log printed so): no still
    window, and the error quotes the quietest window and a threshold above it, which then finds the rest."""
    rng = np.random.default_rng(63)
    t = np.arange(600) / 10.0
    raw = np.round(np.array([1.04, 0.01, 0.09]) + rng.normal(scale=0.012, size=(600, 3)), 2)
    csv = tmp_path / "still_acc.csv"
    np.savetxt(csv, np.column_stack([t, raw]), delimiter=",", header="t,x,y,z", comments="")
    code = main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "-o", str(tmp_path / "out.yaml")])
    err = capsys.readouterr().err
    assert code != 0 and "no still periods found" in err and "its quietest window: CV" in err, err
    value = err.split("--set accel.gate_cv_threshold=")[1].split()[0]
    assert 0.012 < float(value) < 0.05, err
    main(["calibrate", str(csv), "--sensor", "accel", "--unit", "g", "-o", str(tmp_path / "out.yaml"), "--set",
          f"accel.gate_cv_threshold={value}"])
    cap = capsys.readouterr()
    assert "static recording" in cap.out + cap.err and "each axis pointing up and down" in cap.out + cap.err


def test_zero_rows_are_called_zero_rows_and_counted_once() -> None:
    """All-zero rows: dropped as ``zero`` once each and called so, never "last |v| = 0 > limit"."""
    intake = Intake(PipelineConfig.for_sensor("mag", "T"))
    for i in range(5):
        intake.take(float(i), (0.0, 0.0, 0.0))
    intake.take(5.0, (1.0, 0.0, 0.0))  # 1 T: above the limit
    for i in range(6, 9):
        intake.take(float(i), (0, 0, 0))
    assert intake.dropped["zero"] == 8 and intake.dropped["magnitude"] == 1 and intake.zero_rows == 8
    summary = intake.drop_summary()
    assert "8 all-zero rows" in summary and "|v| = 0 " not in summary, summary


def _replay(path: Path) -> SensorCalibrator:
    return replay(path, sensor="accel", unit="g", status_every=0.0, progress=False)["calibrators"]["accel"]


def test_the_lsm9ds1_static_poses_calibrate(real_recording: Callable[[str], Path]) -> None:
    """ck_lsm9ds1_static_poses_acc: 160 poses of 100 samples back to back; each fits one 2 s window, and they calibrate."""
    cal = _replay(real_recording("ck_lsm9ds1_static_poses_acc.csv"))
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert cal.kept >= 60
    assert cal.calibration is not None and abs(cal.calibration.raw_radius - 1.0) < 0.05


@pytest.mark.parametrize("name", ["sunsided_mpu6050_unmoved-with-x-pointing-forward_acc.csv",
                                  "sunsided_mpu6050_unmoved-with-z-pointing-front-and-x-up_acc.csv",
                                  "sunsided_mpu6050_unmoved-with-z-pointing-front-and-y-down_acc.csv"])
def test_an_mpu6050_on_a_desk_is_still(real_recording: Callable[[str], Path], name: str) -> None:
    """The MPU6050 at rest (4-5e-3 g per axis) is found still by the learning gate, not by Gietzelt's fixed one."""
    rec = read_recording(real_recording(name), sensor="accel")
    learnt, fixed = InactivityGate(learn=True), InactivityGate()
    for t, v in zip(rec.t, rec.raw, strict=True):
        learnt.push(t, v)
        fixed.push(t, v)
    assert learnt.counters["emitted"] >= 40
    assert fixed.counters["emitted"] == 0
    assert "learnt from" in learnt.learnt


def test_the_mpu6050_full_sphere_move_is_not_still(real_recording: Callable[[str], Path]) -> None:
    """The MPU6050 turned by hand all through its recording: the learning gate finds nothing still."""
    rec = read_recording(real_recording("sunsided_mpu6050_full_sphere_acc.csv"), sensor="accel")
    gate = InactivityGate(learn=True)
    for t, v in zip(rec.t, rec.raw, strict=True):
        gate.push(t, v)
    assert gate.counters["emitted"] == 0
    assert gate.thresholds == (3e-3, 3e-3)  # a move taught it nothing
