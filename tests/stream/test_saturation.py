"""Saturated axes (``stream.saturation``): an axis clipped at the end of the sensor's range is found and its samples
dropped, in the stream and in ``margcal calibrate``; nothing is found where nothing is clipped (the independent
generator's motions, in tesla and in counts, and every real recording). Streams of the independent generator, seeded."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from conftest import INDEPENDENT
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.cli import main
from ros_margcal.model.calibration_file import load_calibrations
from ros_margcal.recordings.read import read_recording
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator
from ros_margcal.stream.saturation import RailWatch, on_rails

GEN: ModuleType = INDEPENDENT


def _tumble(seed: int, *, unit: str = "T", clip: float | None = None, seconds: float = 60.0) -> tuple[dict, np.ndarray]:
    """An independent tumble with a 30 uT hard iron; ``clip``: its x axis clipped at that share of its largest |x|."""
    rec = GEN.generate("mag", "tumble", duration_s=seconds, rate_hz=50.0, seed=seed, hard_iron_mag=30e-6,
                       symmetric_soft_iron=True, unit=unit)
    x = np.array(rec["xyz"], dtype=np.float64)
    if clip is not None:
        lim = clip * np.abs(x[:, 0]).max()
        x[:, 0] = np.clip(x[:, 0], -lim, lim)
    return rec, x


@pytest.mark.parametrize("unit", ["T", "counts"])
@pytest.mark.parametrize("clip", [0.6, 0.4])
def test_a_clipped_axis_is_found_at_its_value_and_nothing_else_is_dropped(unit: str, clip: float) -> None:
    _, x = _tumble(31, unit=unit, clip=clip)
    watch = RailWatch()
    flagged = np.array([watch.push(*v) for v in x.tolist()])
    top = x[:, 0].max()
    assert (0, top) in watch.rails
    assert all(k == 0 and abs(v) == top for k, v in watch.rails)
    assert np.all(np.abs(x[flagged, 0]) == top)  # only samples on the rail
    assert flagged.sum() >= 0.95 * np.sum(np.abs(x[:, 0]) == top)  # all of them but the runs that found it
    mask, found = on_rails(x)  # a batch drops the runs that found the rails too
    assert found.rails == watch.rails
    assert np.array_equal(mask, np.isin(x[:, 0], [v for _, v in watch.rails]))


@pytest.mark.parametrize("unit", ["T", "counts"])
@pytest.mark.parametrize(("motion", "kw"), [("tumble", {}), ("ground", {"tilt_deg": 5.0}), ("car", {}), ("band", {}),
                                            ("hemisphere", {})])
def test_nothing_is_found_where_nothing_is_clipped(motion: str, kw: dict, unit: str) -> None:
    for seed in (41, 42):
        rec = GEN.generate("mag", motion, duration_s=120.0, rate_hz=50.0, seed=seed, hard_iron_mag=30e-6, unit=unit, **kw)
        mask, watch = on_rails(rec["xyz"])
        assert not mask.any() and not watch.rails, (motion, unit, seed, watch.rails)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), axis=st.integers(0, 2), sign=st.sampled_from([-1.0, 1.0]),
       noise=st.floats(1e-4, 1e-2), quantum=st.floats(1e-4, 5e-3))
def test_a_sensor_at_rest_never_makes_a_rail(seed: int, axis: int, sign: float, noise: float, quantum: float) -> None:
    """Gravity (or the field) along one axis, quantised noise of up to 1 % on all three: the axis's top count is held
    again and again while the others' noise wanders, and nothing may be called saturated."""
    rng = np.random.default_rng(seed)
    v = rng.normal(0.0, noise, (2000, 3))
    v[:, axis] += sign
    v = np.round(v / quantum) * quantum
    mask, watch = on_rails(v)
    assert not mask.any(), watch.rails


def test_no_real_recording_has_a_rail(real_data_dir: Path) -> None:
    """Quantised sensors at rest, wobbling, turning slowly, a magnet on a table: none saturates."""
    files = sorted(real_data_dir.glob("*.csv"))
    assert files
    for f in files:
        rec = read_recording(f, sensor="accel" if "_acc" in f.name else "mag", order="file")
        watch = RailWatch()
        dropped = sum(watch.push(*v) for v in np.asarray(rec.raw, dtype=np.float64).tolist())
        assert dropped == 0, (f.name, watch.rails)


def test_the_stream_drops_a_clipped_axis_says_so_and_calibrates_as_if_unclipped() -> None:
    """A tumble whose x axis reads at most 40 uT (a fifth of the samples beyond): before, the stream published a
    calibration 4 deg off at 30 deg tilt after 41 s and refused every refit after it. The early fits of the first
    seconds, before the rail is found, hold clipped readings: within the partial standard (2.5 deg at 30 deg,
    ``max_heading_p95_deg``), and every calibration once the rail is found within 1 deg."""
    rec = GEN.generate("mag", "tumble", duration_s=120.0, rate_hz=50.0, seed=21, hard_iron_mag=30e-6,
                       symmetric_soft_iron=True)
    x = np.array(rec["xyz"], dtype=np.float64)
    x[:, 0] = np.clip(x[:, 0], -40e-6, 40e-6)
    assert np.mean(np.abs(rec["xyz"][:, 0]) > 40e-6) > 0.2
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag"))
    published = [(cal.dropped["saturated"] > 0, e.calibration) for t, v in zip(rec["t"].tolist(), x, strict=True)
                 for e in cal.push(t, v) if e.kind is EventKind.CALIBRATED]
    errors = [(found, GEN.heading_p95(c.matrix, c.offset, rec["truth"], tilt_deg=30.0)) for found, c in published]
    assert any(found for found, _ in errors)
    assert max(e for _, e in errors) < PipelineConfig.for_sensor("mag").max_heading_p95_deg
    assert max(e for found, e in errors if found) < 1.0
    assert cal.dropped["saturated"] >= 0.9 * np.sum(x[:, 0] == 40e-6)
    assert cal.seen == cal.passed + sum(cal.dropped.values())
    st = cal.status(float(rec["t"][-1]))
    assert "dropped as saturated: x at +4e-05 T" in st.message


def test_an_overflow_code_is_a_rail_too() -> None:
    """An HMC5883L in counts reads -4096 on an axis whose ADC overflows, whatever the sign (its data sheet): here a
    quarter of the x readings. Before, the code inflated the scale the rule measured against: nothing was found and
    the stream never calibrated."""
    rec, x = _tumble(22, unit="counts", seconds=120.0)
    over = np.abs(x[:, 0]) > 0.6 * np.abs(x[:, 0]).max()
    assert over.mean() > 0.2
    x[over, 0] = -4096.0
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", "counts"))
    published = [e.calibration for t, v in zip(rec["t"].tolist(), x, strict=True) for e in cal.push(t, v)
                 if e.kind is EventKind.CALIBRATED]
    assert published
    assert max(GEN.heading_p95(c.matrix, c.offset, rec["truth"], tilt_deg=30.0) for c in published) < 1.0
    assert cal.dropped["saturated"] >= 0.95 * over.sum()
    assert "dropped as saturated: x at -4096 counts" in cal.status(float(rec["t"][-1])).message


def test_calibrate_drops_the_clipped_rows_and_fits_the_rest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Half the x range clipped (36 % of the rows): before, ``margcal calibrate`` refused the recording for a 7.8 %
    residual, naming no cause."""
    rec, x = _tumble(21, unit="uT", clip=0.5, seconds=120.0)
    csv = tmp_path / "clipped_mag.csv"
    np.savetxt(csv, np.c_[rec["t"], x], delimiter=",", header="t,x,y,z", comments="", fmt="%.9g")
    out = tmp_path / "cal.yaml"
    code = main(["calibrate", str(csv), "--unit", "uT", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"samples dropped as saturated: x at +{x[:, 0].max():.6g} uT" in err
    cal = next(iter(load_calibrations(out).values()))
    assert np.linalg.norm(cal.offset - rec["truth"]["offset"]) < 0.5  # uT, of a 30 uT hard iron
