"""The live view's geometry (``stream/view.py``): what RViz and ``replay --plot`` show is the data and the fit."""

from __future__ import annotations

import numpy as np

from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.view import bin_directions, coverage_view


def _calibrated() -> tuple[SensorCalibrator, sim.Recording]:
    truth = sim.random_sensor(np.random.default_rng(21), "mag")
    rec = sim.magnetometer_stream(truth, 60.0, 50.0, np.random.default_rng(22), motion="tumble")
    c = SensorCalibrator("mag")
    for t, v in zip(rec.t.tolist(), rec.raw, strict=True):
        c.push(t, v)
    assert c.calibration is not None
    return c, rec


def test_bin_directions_are_the_buffers_bins() -> None:
    """Each bin's centre direction falls in that bin of the buffer (the same grid, the same order)."""
    c = SensorCalibrator("mag")
    buf = c.buffer
    dirs = bin_directions(buf.n_bands, buf.n_sectors)
    assert dirs.shape == (buf.n_bins, 3)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    centre, r = buf.center, 50e-6
    assert [buf.bin_of(centre + r * d) for d in dirs] == list(range(buf.n_bins))


def test_the_view_of_a_calibrated_sensor_shows_its_samples_on_the_fitted_ellipsoid() -> None:
    """Uncalibrated: no ellipsoid. Calibrated: the buffered samples lie on the drawn ellipsoid (d^T A d = 1)."""
    empty = coverage_view(SensorCalibrator("mag"))
    assert empty.axes is None and empty.radii is None and len(empty.points) == 0 and empty.state == "collecting"
    c, _ = _calibrated()
    v = coverage_view(c)
    assert v.state == "calibrated" and len(v.points) == len(c.buffer.points()) > 100
    assert abs(np.linalg.det(v.axes) - 1.0) < 1e-9  # a rotation: RViz takes it as a quaternion
    a = v.axes @ np.diag(1.0 / v.radii**2) @ v.axes.T
    q = np.einsum("ij,jk,ik->i", v.points, a, v.points)
    assert np.median(np.abs(q - 1.0)) < 0.02  # on the ellipsoid up to noise
    assert 0.9 < np.median(np.linalg.norm(v.points, axis=1)) < 1.1  # one display unit is one field radius
    counts = np.asarray(c.buffer.bin_counts())
    assert len(v.bins) == int(np.sum(counts > 0)) and abs(v.coverage - np.mean(counts > 0)) < 1e-12
