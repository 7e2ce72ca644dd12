"""The sample path's speed cuts change no result: the spike filter's lazy sort, a full fit's figures read later."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.intake import SpikeFilter
from ros_margcal.stream.status import EventKind


class _SortEveryStep(SpikeFilter):
    """The filter as it was: the usual step sorted out of the last steps at every sample."""

    def _step(self, v: tuple[float, float, float]) -> float:
        step = math.dist(self._last, v)
        self._usual = sorted(self._steps)[(3 * len(self._steps)) // 4] if self._steps else step
        self._steps.append(step)
        if 0.0 < step < self._quantum:
            self._quantum = step
        self._last = v
        return step


def _spiky_stream(rng: np.random.Generator, n: int = 3000) -> list[tuple[float, float, float, float, None]]:
    """A turning field (some steps quantised to 0) with lone spikes, two-sample spikes and real jumps."""
    ang = np.cumsum(rng.normal(0.0, 0.05, (n, 2)), axis=0)
    v = 50.0 * np.c_[np.cos(ang[:, 0]) * np.cos(ang[:, 1]), np.sin(ang[:, 0]) * np.cos(ang[:, 1]), np.sin(ang[:, 1])]
    v = np.round(v, 1)  # a quantised sensor: some steps are 0
    for i in rng.choice(np.arange(10, n - 10), 60, replace=False):
        v[i] += rng.normal(0.0, 40.0, 3)  # a spike
    for i in rng.choice(np.arange(10, n - 10), 10, replace=False):
        v[i:i + 2] += rng.normal(0.0, 30.0, 3)  # a two-sample spike
    for i in (700, 1900):
        v[i:] += 25.0  # a real jump: stays
    return [(0.02 * k, *map(float, row), None) for k, row in enumerate(v)]


def test_the_lazy_usual_step_decides_every_sample_as_the_sorted_one() -> None:
    """Reading the usual step only beyond the cheap bound hands on and drops exactly the same samples."""
    stream = _spiky_stream(np.random.default_rng(5))
    new, old = SpikeFilter(), _SortEveryStep()
    out_new, out_old = [], []
    for s in stream:
        out_new.append(new.push(s))
        out_old.append(old.push(s))
    assert out_new == out_old
    dropped = sum(n for _, n in out_new)
    assert 40 <= dropped <= 100  # the spikes were there to be found, and found


@pytest.fixture(scope="module")
def tumble() -> tuple[Calibration, sim.Recording]:
    truth = sim.random_sensor(np.random.default_rng(11), "mag")
    return truth, sim.magnetometer_stream(truth, 30.0, 50.0, np.random.default_rng(12), motion="tumble")


def test_a_full_fits_figures_are_those_the_installing_push_would_have_computed(tumble) -> None:
    """Inline, the push that installs a full fit leaves its heading figures for later; the status then shows the
    figures a calibrator computing them at once (deferred mode, ``run_pending`` after each push) shows."""
    _, rec = tumble
    inline, deferred = SensorCalibrator("mag"), SensorCalibrator("mag")
    deferred.defer_evaluation = True
    later = 0
    events, events_d = [], []
    figures, figures_d = {}, {}  # the stamp of each full calibration -> its status's (level, 30 deg) figures
    for t, v in zip(rec.t.tolist(), rec.raw.tolist(), strict=True):
        ev = inline.push(t, v)
        ev_d = deferred.push(t, v) + deferred.run_pending()
        events += [(e.kind, e.t) for e in ev]
        events_d += [(e.kind, e.t) for e in ev_d]
        for cal, got, out in ((inline, ev, figures), (deferred, ev_d, figures_d)):
            for e in got:
                if e.kind is EventKind.CALIBRATED and "partial" not in e.message:
                    later += cal is inline and inline._figures_due is not None  # not computed by the installing push
                    st = cal.status()
                    assert cal._figures_due is None
                    out[e.t] = (st.heading_p95_level_deg, st.heading_p95_tilt30_deg)
    assert events == events_d  # a fit in steps installs a few pushes later, with the stamp of the push that started it
    assert figures.keys() == figures_d.keys() and later >= 1
    for k, (level, tilt30) in figures.items():
        assert math.isfinite(tilt30)
        assert level == pytest.approx(figures_d[k][0], rel=1e-12) and tilt30 == pytest.approx(figures_d[k][1], rel=1e-12)


def _published_after_jump(independent, monkeypatch=None) -> list[tuple[float, float]]:
    """(stamp, 30 deg heading p95 against the truth after the jump) of each calibration published after it."""
    rec = independent.generate("mag", "tumble", 80.0, 50.0, 3, hard_iron_mag=30e-6, symmetric_soft_iron=True,
                               effect="hard_iron_jump", magnitude=20.0 / 48.0, t_jump=60.0, gyro_scale=0.03)
    after = {**rec["truth"], "offset": rec["truth"]["offset_after"]}
    cal = SensorCalibrator("mag")
    out = []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and t > 60.0:
                c = e.calibration
                out.append((t, independent.heading_p95(c.matrix, c.offset, after, 30.0)))
    return out


def test_a_recheck_after_a_hard_iron_jump_publishes_no_calibration_of_before_it(independent, monkeypatch) -> None:
    """Tuning seed 3 of scripts/bench_speed.py's jump: a recheck 10 s after the jump re-centred the buffer of before
    it (its samples since are outliers) and published it, 49 deg off, for 8 s; now it is refused and the first
    calibration after the jump is the new sensor's."""
    got = _published_after_jump(independent)
    assert got, "the new sensor was calibrated"
    assert max(p for _, p in got) < 2.0
    monkeypatch.setattr(SensorCalibrator, "_misses_recent", lambda self, job, cal: "")
    before = _published_after_jump(independent)
    assert max(p for _, p in before) > 20.0  # the check is what keeps it out
