"""Issue 14: a ground robot's magnetometer (yaw turns, small tilt) gets a partial calibration that says so.

On the independent generator (tests/independent: no code shared with the package). The figures over
many seeds are in scripts/bench_ground_robot.py; here one fixed seed per claim.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.model.errors import ConfigError
from ros_margcal.ros.messages import status_to_diagnostic
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator
from ros_margcal.stream.observable import (
    DEFAULT_INCLINATION_DEG,
    INFER_INCLINATION_MAX_TILT_DEG,
    sphere_radius,
    tilt_seen_deg,
)


@dataclass
class _KeyValue:
    key: str
    value: str


@dataclass
class _Diagnostic:
    level: int
    name: str
    message: str
    hardware_id: str
    values: list[_KeyValue]


def _feed(cal: SensorCalibrator, rec: dict[str, Any]) -> list[Any]:
    out = []
    for t, v in zip(rec["t"].tolist(), rec["xyz"], strict=True):
        out += [e for e in cal.push(t, v) if e.kind is EventKind.CALIBRATED]
    return out


GEN: ModuleType = INDEPENDENT


@pytest.fixture(scope="module")
def ground() -> dict[str, Any]:
    return GEN.generate("mag", "ground", duration_s=300.0, rate_hz=50.0, seed=22, tilt_deg=5.0,
                        symmetric_soft_iron=True, hard_iron_mag=30e-6)


def test_a_ground_robot_gets_a_partial_calibration_with_its_heading_error(ground: dict[str, Any]) -> None:
    gen, tr = GEN, ground["truth"]
    cal = SensorCalibrator("mag")
    events = _feed(cal, ground)
    assert events, cal.status().message
    assert events[0].t <= 300.0 and "partial" in events[0].message
    st = cal.status()
    assert st.state.value == "calibrated"
    assert set(st.updated_parameters) | set(st.prior_parameters) == {
        "b_x", "b_y", "b_z", "w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz"}
    assert {"b_x", "b_y", "w_xx", "w_yy", "w_xy"} <= set(st.updated_parameters)  # what turning in yaw determines
    assert st.partial and "w_zz" in st.prior_parameters  # 5 deg of tilt: the vertical gain stays at the prior
    assert st.heading_p95_level_deg is not None and st.heading_p95_tilt30_deg is not None
    assert 0.0 < st.heading_p95_level_deg <= st.heading_p95_tilt30_deg
    assert st.heading_typical_level_deg is not None and st.heading_typical_tilt30_deg is not None
    assert 0.0 < st.heading_typical_level_deg < st.heading_p95_level_deg  # the median of what the bound bounds
    assert 0.0 < st.heading_typical_tilt30_deg < st.heading_p95_tilt30_deg
    assert "heading p95" in st.message and "typical" in st.message and "updated" in st.message
    # every published calibration within 5 deg level (this seed: 0.7-1.6 deg); the 95 % bound holds and stays useful
    # (the quantile bound with the offset's slow noise is 2-3x the measured p95 at the median: bench_heading_bound.py),
    # the typical figure within a factor 2
    c = cal.calibration
    measured = [gen.heading_p95(e.calibration.matrix, e.calibration.offset, tr, 0.0) for e in events]
    assert max(measured) <= 2.0
    assert 1.0 <= st.heading_p95_level_deg / measured[-1] <= 4.0
    assert 0.5 <= st.heading_typical_level_deg / measured[-1] <= 2.0
    assert st.heading_p95_level_deg <= 2.5  # published under the 2.5 deg rule at the tilt seen (level is lower)
    assert 2.0 <= tilt_seen_deg(c, ground["xyz"][::10]) <= 6.0 and st.tilt_seen_deg is not None
    # the keys of /calib/status
    diag = status_to_diagnostic(st, _Diagnostic, _KeyValue)
    values = {kv.key: kv.value for kv in diag.values}
    assert values["updated_parameters"].split() == list(st.updated_parameters)
    assert values["prior_parameters"].split() == list(st.prior_parameters)
    assert float(values["heading_p95_level_deg"]) == pytest.approx(st.heading_p95_level_deg, rel=1e-2)
    assert float(values["heading_p95_tilt30_deg"]) == pytest.approx(st.heading_p95_tilt30_deg, rel=1e-2)
    assert float(values["heading_typical_level_deg"]) == pytest.approx(st.heading_typical_level_deg, rel=1e-2)
    assert float(values["heading_typical_tilt30_deg"]) == pytest.approx(st.heading_typical_tilt30_deg, rel=1e-2)
    assert values["partial"] in ("true", "false")
    d = st.to_dict()
    assert d["updated_parameters"] == list(st.updated_parameters) and d["heading_p95_level_deg"] == st.heading_p95_level_deg
    assert d["heading_typical_tilt30_deg"] == st.heading_typical_tilt30_deg
    # the figures' inclination, inferred from the ring (the generator's field: 60 deg), in every form
    assert st.heading_inclination_deg == pytest.approx(60.0, abs=5.0)
    assert float(values["heading_inclination_deg"]) == pytest.approx(st.heading_inclination_deg, rel=1e-2)
    assert d["heading_inclination_deg"] == st.heading_inclination_deg
    assert f"{st.heading_inclination_deg:.3g} deg field inclination" in st.message


def test_a_rings_heading_figures_are_at_the_inclination_of_its_field() -> None:
    """Where the field dips 20 deg (not the 60 deg assumed without data), a ground robot's figures say so and are
    the heading error there: the bound covers the error measured at the generator's own field."""
    rec = GEN.generate("mag", "ground", duration_s=300.0, rate_hz=50.0, seed=23, tilt_deg=5.0, inclination_deg=20.0,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6)
    cal = SensorCalibrator("mag")
    events = _feed(cal, rec)
    assert events, cal.status().message
    st = cal.status()
    assert st.heading_inclination_deg == pytest.approx(20.0, abs=5.0)
    c = cal.calibration
    measured = GEN.heading_p95(c.matrix, c.offset, rec["truth"], 0.0)
    assert st.heading_p95_level_deg is not None and measured <= st.heading_p95_level_deg


@pytest.mark.parametrize("seed", [3, 4])
def test_a_ring_near_the_magnetic_equator_is_a_ring(seed: int) -> None:
    """At 30 deg of inclination a level circle of directions crosses 8 of the 12 regions of ``regions_seen``: a +-5 deg
    ground robot's fits were taken for rich motion ("not a ring or band", judged at 30 deg tilt) and it did not
    calibrate in 150 s (seeds 3-5; one in 300 s at 232 s). A ring tilted at most INFER_INCLINATION_MAX_TILT_DEG is a
    ring: calibrated within a minute, its level bound covering the truth, at its own field's inclination."""
    rec = GEN.generate("mag", "ground", duration_s=150.0, rate_hz=40.0, seed=seed, tilt_deg=5.0, inclination_deg=30.0,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6)
    cal = SensorCalibrator("mag")
    events = _feed(cal, rec)
    assert events and events[0].t <= 60.0, cal.status().message
    st = cal.status()
    assert "not a ring or band" not in st.message, st.message
    assert st.heading_inclination_deg == pytest.approx(30.0, abs=5.0)
    for e in events:
        measured = GEN.heading_p95(e.calibration.matrix, e.calibration.offset, rec["truth"], 0.0)
        assert measured <= 0.5, (e.t, measured)
    c = cal.calibration
    assert GEN.heading_p95(c.matrix, c.offset, rec["truth"], 0.0) <= st.heading_p95_level_deg


def test_a_ring_where_the_field_dips_steeply_says_a_gyro_would_help() -> None:
    """At 72 deg of inclination a +-5 deg ground robot without the gyro is refused for minutes (its tilts leak 3x into
    the heading): the refusal says why and that the Imu's rates help; with them it calibrates within a minute
    (``observable.STEEP_FIELD_DEG``)."""
    rec = GEN.generate("mag", "ground", duration_s=120.0, rate_hz=40.0, seed=3, tilt_deg=5.0, inclination_deg=72.0,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6, gyro_scale=0.03)
    alone = SensorCalibrator("mag")
    assert not _feed(alone, rec)
    assert "the field dips 71 deg" in alone.status().message or "the field dips 72 deg" in alone.status().message
    assert "with the Imu's rates such a ring calibrates sooner" in alone.status().message
    aided = SensorCalibrator("mag")
    events = [e for t, v, g in zip(rec["t"].tolist(), rec["xyz"].tolist(), rec["gyro"].tolist(), strict=True)
              for e in aided.push(t, v, g) if e.kind is EventKind.CALIBRATED]
    assert events and events[0].t <= 60.0, aided.status().message
    assert "the field dips" not in aided.status().message
    c = aided.calibration
    assert GEN.heading_p95(c.matrix, c.offset, rec["truth"], 0.0) <= 1.0


def test_a_bands_heading_figures_take_the_default_inclination() -> None:
    """A ±20 deg band tilts too much for "z up on average": its mean vertical share reads the field 44-58 deg
    (bench seeds 900-904; 60 deg true); its figures take 60 deg and say so."""
    rec = GEN.generate("mag", "band", duration_s=120.0, rate_hz=50.0, seed=903, band_deg=20.0,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6)
    cal = SensorCalibrator("mag")
    events = _feed(cal, rec)
    assert events, cal.status().message
    st = cal.status()
    assert st.tilt_seen_deg is not None and st.tilt_seen_deg > INFER_INCLINATION_MAX_TILT_DEG
    assert st.heading_inclination_deg == DEFAULT_INCLINATION_DEG
    assert "60 deg field inclination" in st.message


def test_without_the_partial_path_a_ground_robot_never_calibrates(ground: dict[str, Any]) -> None:
    """``partial_fit: false`` is today's rule: the full validator refuses a ring for ever."""
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", partial_fit=False))
    assert _feed(cal, ground) == []
    st = cal.status()
    assert st.state.value == "collecting" and st.heading_p95_level_deg is None and not st.updated_parameters


def test_a_partial_fit_that_is_not_good_enough_says_why(ground: dict[str, Any]) -> None:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", max_heading_p95_deg=0.01))
    assert _feed(cal, ground) == []
    st = cal.status()
    assert st.state.value == "collecting"
    assert "predicted heading error" in st.message and "> 0.01 deg" in st.message


@pytest.fixture(scope="module")
def tumble() -> dict[str, Any]:
    """A full tumble of the independent generator (the package's simulator tumbles slowly: its first
    half minute is a band, which the partial path may calibrate)."""
    return GEN.generate("mag", "tumble", duration_s=30.0, rate_hz=50.0, seed=1, hard_iron_mag=30e-6,
                        symmetric_soft_iron=True)


def test_the_full_path_is_unchanged_on_a_tumble(tumble: dict[str, Any]) -> None:
    """Rich motion without the early fit: the same calibrations at the same times with and without the
    partial path (a ring or band only)."""
    with_partial = _feed(SensorCalibrator("mag", PipelineConfig.for_sensor("mag", early_fit=False)), tumble)
    without = _feed(SensorCalibrator("mag", PipelineConfig.for_sensor("mag", partial_fit=False)), tumble)
    assert with_partial and [e.t for e in with_partial] == [e.t for e in without]
    for a, b in zip(with_partial, without, strict=True):
        np.testing.assert_array_equal(a.calibration.offset, b.calibration.offset)
        assert "partial" not in a.message


def test_the_early_fit_publishes_sooner_and_the_full_path_takes_over(tumble: dict[str, Any]) -> None:
    cal = SensorCalibrator("mag")
    early = _feed(cal, tumble)
    full = _feed(SensorCalibrator("mag", PipelineConfig.for_sensor("mag", partial_fit=False)), tumble)
    assert early[0].t < full[0].t and "partial:" in early[0].message
    c, tr = early[0].calibration, tumble["truth"]
    assert GEN.heading_p95(c.matrix, c.offset, tr, tilt_deg=30.0) <= 1.0  # measured, against the truth
    # later fits are the full path's (no MAP yardstick in their not-worse check): the status lists no MAP parameters
    assert any("partial:" not in e.message for e in early[1:])
    st = cal.status()
    assert not st.updated_parameters and st.heading_p95_level_deg is not None


def test_new_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="partial_fit"):
        PipelineConfig.for_sensor("mag", partial_fit=1)
    with pytest.raises(ConfigError, match="max_heading_p95_deg"):
        PipelineConfig.for_sensor("mag", max_heading_p95_deg=0.0)
    with pytest.raises(ConfigError, match="partial_samples"):
        PipelineConfig.for_sensor("mag", partial_samples=5)


def test_sphere_radius_of_a_sphere() -> None:
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    pts = 2.5 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([1.0, -2.0, 0.5])
    assert sphere_radius(pts) == pytest.approx(2.5, rel=1e-9)
    assert math.isnan(sphere_radius(np.zeros((10, 3))))


def test_replay_prints_the_heading_error_and_the_partial_parameters(ground: dict[str, Any], tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    import argparse
    import json

    from ros_margcal.cli import replay as replay_cli

    csv = tmp_path / "ground_mag.csv"
    GEN.write_csv(csv, {"t": ground["t"], "xyz": ground["xyz"]})
    parser = argparse.ArgumentParser()
    replay_cli.register(parser.add_subparsers())
    out_json = tmp_path / "out.json"
    args = parser.parse_args(["replay", str(csv), "--sensor", "mag", "-q", "--json", str(out_json)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "heading error (predicted p95, 95 % bound, " in text and "deg field inclination):" in text
    assert "deg level" in text
    assert "heading error (predicted p95, typical):" in text
    assert "partial calibration (data tilted up to" in text and "from the prior: w_zz" in text
    doc = json.loads(out_json.read_text())["sensors"]["mag"]
    assert doc["heading_p95_deg"]["level"] > 0 and "w_zz" in doc["partial"]["from_prior"]
    assert 0 < doc["heading_typical_deg"]["level"] < doc["heading_p95_deg"]["level"]
    assert doc["status"]["partial"] is True
