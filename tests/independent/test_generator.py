"""Properties of the independent recording generator (numpy only, no ros_margcal import)."""

from __future__ import annotations

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import numpy as np
import pytest


def _cal_norms(rec, offset=None):
    tr = rec["truth"]
    off = tr["offset"] if offset is None else offset
    return np.linalg.norm((rec["xyz"] - off) @ tr["W"].T, axis=1)


def test_deterministic_for_a_seed():
    a = gen.generate("mag", "tumble", 10.0, 50.0, seed=7, effect="bias_drift", with_temp=True, jitter_s=0.002)
    b = gen.generate("mag", "tumble", 10.0, 50.0, seed=7, effect="bias_drift", with_temp=True, jitter_s=0.002)
    c = gen.generate("mag", "tumble", 10.0, 50.0, seed=8, effect="bias_drift", with_temp=True, jitter_s=0.002)
    for key in ("t", "xyz", "gyro", "temp"):
        np.testing.assert_array_equal(a[key], b[key])
    np.testing.assert_array_equal(a["truth"]["W"], b["truth"]["W"])
    assert not np.allclose(a["xyz"], c["xyz"])
    assert a["t"][0] == 0.0 and np.all(np.diff(a["t"]) > 0)


def test_motion_independent_of_effect():
    a = gen.generate("mag", "ground", 10.0, 50.0, seed=3)
    b = gen.generate("mag", "ground", 10.0, 50.0, seed=3, effect="nonlinearity")
    np.testing.assert_array_equal(a["truth"]["q"], b["truth"]["q"])
    np.testing.assert_array_equal(a["truth"]["offset"], b["truth"]["offset"])


@pytest.mark.parametrize("motion", gen.MOTIONS)
@pytest.mark.parametrize("unit", ["T", "uT"])
def test_truth_calibration_is_exact_without_noise(motion, unit):
    rec = gen.generate("mag", motion, 8.0, 50.0, seed=1, noise=0.0, unit=unit)
    tr = rec["truth"]
    assert np.max(np.abs(_cal_norms(rec) / tr["norm"] - 1)) < 1e-9
    np.testing.assert_allclose(tr["W"] @ tr["M"], np.eye(3), atol=1e-12)
    assert tr["norm"] == pytest.approx(48e-6 if unit == "T" else 48.0)
    # gyro is consistent with the attitude track: integrating the true rates reproduces q
    q = tr["q"]
    dq = gen._qexp(tr["omega"][:-1] * np.diff(rec["t"])[:, None])
    np.testing.assert_allclose(np.abs(np.sum(gen._qmul(q[:-1], dq) * q[1:], axis=1)), 1.0, atol=1e-12)


def test_accel_rest_periods_are_gravity_only():
    rec = gen.generate("accel", "rest_and_move", 20.0, 100.0, seed=2, noise=0.0, rest_s=1.5, move_s=2.5)
    tr, still = rec["truth"], rec["truth"]["still"]
    assert 0.3 < still.mean() < 0.5
    norms = _cal_norms(rec)
    assert np.max(np.abs(norms[still] / gen.G0 - 1)) < 1e-9
    assert np.all(tr["omega"][still] == 0.0)
    assert np.all(np.abs(rec["gyro"][still]) < 0.05)
    assert np.std(norms[~still]) > 0.05 * gen.G0  # linear acceleration while moving
    # attitude changes between successive rest periods
    starts = np.flatnonzero(np.diff(still.astype(int)) == -1)
    assert np.rad2deg(np.linalg.norm(gen._qlog(gen._qmul(gen._qconj(tr["q"][starts[0]]), tr["q"][starts[1]])))) > 20


def test_attitude_bounds_per_motion():
    g = gen.generate("mag", "ground", 30.0, 50.0, seed=4, tilt_deg=5.0)
    rpy = g["truth"]["rpy_deg"]
    assert np.max(np.abs(rpy[:, :2])) <= 5.0 + 1e-6
    assert np.ptp(np.unwrap(np.deg2rad(rpy[:, 2]))) > np.pi / 2  # it does turn
    assert np.mean(np.abs(np.diff(np.unwrap(np.deg2rad(rpy[:, 2])))) < 1e-6) > 0.1  # and drives straight
    b = gen.generate("mag", "band", 20.0, 50.0, seed=4, band_deg=20.0)
    assert np.max(np.abs(b["truth"]["rpy_deg"][:, :2])) <= 20.0 + 1e-6
    h = gen.generate("mag", "hemisphere", 20.0, 50.0, seed=4)
    assert np.min(gen.quat_to_matrix(h["truth"]["q"])[:, 2, 2]) > 0.0


def test_counts_are_integers():
    rec = gen.generate("mag", "tumble", 5.0, 50.0, seed=5, unit="counts")
    assert np.all(rec["xyz"] == np.round(rec["xyz"]))
    assert rec["truth"]["norm"] == pytest.approx(48e-6 / gen.DEFAULT_LSB["mag"])
    assert rel_norm_err(rec) < 0.02


def rel_norm_err(rec):
    return float(np.max(np.abs(_cal_norms(rec) / rec["truth"]["norm"] - 1)))


def test_hard_iron_jump_moves_offset_at_t_jump():
    rec = gen.generate("mag", "tumble", 10.0, 50.0, seed=6, noise=0.0, effect="hard_iron_jump", magnitude=0.3, t_jump=4.0)
    tr, after = rec["truth"], rec["t"] >= 4.0
    np.testing.assert_allclose(tr["offset_t"][~after], np.tile(tr["offset"], (int((~after).sum()), 1)))
    np.testing.assert_allclose(tr["offset_t"][after], np.tile(tr["offset_after"], (int(after.sum()), 1)))
    assert np.linalg.norm(tr["offset_after"] - tr["offset"]) == pytest.approx(0.3 * tr["norm"])
    assert np.max(np.abs(_cal_norms(rec)[~after] / tr["norm"] - 1)) < 1e-9
    assert np.max(np.abs(_cal_norms(rec, tr["offset_after"])[after] / tr["norm"] - 1)) < 1e-9
    assert np.max(np.abs(_cal_norms(rec)[after] / tr["norm"] - 1)) > 0.05


@pytest.mark.parametrize("effect", gen.EFFECTS)
def test_every_effect_runs_and_has_columns(effect):
    rec = gen.generate("mag", "tumble", 4.0, 25.0, seed=0, effect=effect)
    assert rec["xyz"].shape == (100, 3) and np.all(np.isfinite(rec["xyz"]))
    assert (rec["temp"] is not None) == (effect == "temperature")


def test_heading_p95_truth_vs_identity():
    rec = gen.generate("mag", "ground", 10.0, 50.0, seed=9, noise=0.0, hard_iron=[30.0, 0.0, 0.0], soft_iron=0.0, unit="uT")
    tr = rec["truth"]
    for tilt in (0.0, 30.0):
        assert gen.heading_p95(tr["W"], tr["offset"], tr, tilt_deg=tilt) < 1e-6
        assert gen.heading_p95(np.eye(3), np.zeros(3), tr, tilt_deg=tilt) > 10.0
    res = gen.heading_error_deg(tr["W"], tr["offset"], rec)
    assert res["err_deg"].shape == rec["t"].shape and res["p95"] < 1e-6
    assert res["level_p95"] < 1e-6 and res["tilt30_p95"] < 1e-6
    assert gen.heading_error_deg(np.eye(3), np.zeros(3), rec)["p95"] > 10.0


def test_misalignment_is_invisible_to_norms_but_not_to_heading():
    rec = gen.generate("mag", "tumble", 5.0, 50.0, seed=10, noise=0.0, effect="misalignment", magnitude=3.0)
    tr = rec["truth"]
    w_sensor = np.linalg.inv(tr["M_soft"])  # calibrates magnitudes perfectly, ignores the axis rotation
    norms = np.linalg.norm((rec["xyz"] - tr["offset"]) @ w_sensor.T, axis=1)
    assert np.max(np.abs(norms / tr["norm"] - 1)) < 1e-9
    assert gen.heading_p95(w_sensor, tr["offset"], tr) > 1.0
    assert gen.heading_p95(tr["W"], tr["offset"], tr) < 1e-6


def test_csv_round_trip(tmp_path):
    rec = gen.generate("mag", "static", 3.0, 20.0, seed=11, effect="temperature", unit="uT")
    path = tmp_path / "rec.csv"
    gen.write_csv(path, rec)
    assert path.read_text().splitlines()[0] == "t,x,y,z,temp,gx,gy,gz"
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = np.column_stack([rec["t"], rec["xyz"], rec["temp"], rec["gyro"]])
    np.testing.assert_allclose(data, expected, rtol=1e-10, atol=1e-12)
    names = np.genfromtxt(path, delimiter=",", names=True).dtype.names
    assert names == ("t", "x", "y", "z", "temp", "gx", "gy", "gz")
    rec2 = gen.generate("accel", "static", 2.0, 20.0, seed=11, with_gyro=False)
    gen.write_csv(path, rec2)
    assert path.read_text().splitlines()[0] == "t,x,y,z"


def test_gyro_scale_error_scales_the_rates_and_leaves_the_rest():
    a = gen.generate("mag", "ground", 10.0, 50.0, seed=12)
    b = gen.generate("mag", "ground", 10.0, 50.0, seed=12, gyro_scale=0.03)
    np.testing.assert_array_equal(a["xyz"], b["xyz"])
    np.testing.assert_array_equal(a["truth"]["gyro_bias"], b["truth"]["gyro_bias"])
    assert np.all(a["truth"]["gyro_scale"] == 0.0)
    k = b["truth"]["gyro_scale"]
    assert np.all(np.abs(k) <= 0.03) and np.any(np.abs(k) > 1e-3)
    np.testing.assert_allclose(b["gyro"] - a["gyro"], k * b["truth"]["omega"], atol=1e-15)
