"""Issue 28 item 3 (first good calibration sooner): a tumble whose first seconds are still a ring.

Its first early fit is published as a ring's (on the heading figure at the tilt seen, as any partial fit), good
level but 1.4 deg off at 30 deg of tilt. Before, no early fit ran once something was published, and that
calibration stayed until the full path's fit at 9 s; now early fits go on while its 30 deg figure is above
``early_heading_p95_deg`` (``PartialCalibration._early_open``). A fit of motion tilted past a ring's is published at
``max_heading_p95_deg`` once its directions fill more than half the sphere (``observable.RICH_REGIONS``), else at
``early_heading_p95_deg``. An early fit's blocks of the recent samples leave out a chord across samples dropped
between.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

import ros_margcal.stream.partial as partial_module
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator
from ros_margcal.stream.partial import PartialCalibration

REAL = partial_module.partial_fit_steps


@pytest.fixture(scope="module")
def tumble() -> dict[str, Any]:
    """``scripts/bench_speed.py``'s tumble at 50 Hz, seed 22 (the seed this was found on), its first 12 s."""
    return INDEPENDENT.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=22, gyro_scale=0.03,
                                hard_iron_mag=30e-6, symmetric_soft_iron=True)


def _published(rec: dict[str, Any]) -> list[tuple[float, float | None, float]]:
    """(stamp, tilt seen if published as a ring's, measured 30 deg heading p95) of each calibration in 12 s."""
    cal, out = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED:
                ring = re.search(r"at the tilt seen \(([\d.]+) deg", e.message)
                c = e.calibration
                out.append((e.t, float(ring.group(1)) if ring else None,
                            INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0)))
        if t > 12.0:
            break
    return out


def _first_good(pubs: list[tuple[float, float | None, float]]) -> float:
    return next((t for t, _, err in pubs if err <= 1.0), float("inf"))


def test_an_early_ring_calibration_is_refined_by_early_fits(tumble: dict[str, Any],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    pubs = _published(tumble)
    first_t, first_tilt, first_err = pubs[0]
    assert first_tilt is not None and first_tilt < 45.0 and first_err > 1.0  # a ring's, 1.4 deg off at 30 deg
    assert _first_good(pubs) <= 5.0  # 4.48 s
    monkeypatch.setattr(PartialCalibration, "_early_open", lambda self: self._cal is None)  # the rule before
    before = _published(tumble)
    assert before[0][0] == first_t
    assert _first_good(before) > 8.0  # 8.98 s: the full path's first fit


def test_no_early_fit_runs_once_the_full_path_calibrated(tumble: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    """The refinement is for an early calibration only: after the full path's first calibration (9 s) no early fit
    runs (each costs a few ms, every half second while open)."""
    early: list[float] = []

    def spy(series: Any, *args: Any, **kw: Any) -> Any:
        if kw.get("early"):
            early.append(kw["stamp"])
        return (yield from REAL(series, *args, **kw))

    monkeypatch.setattr(partial_module, "partial_fit_steps", spy)
    cal, full = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), None
    for t, v in zip(tumble["t"].tolist(), tumble["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and "partial:" not in e.message and full is None:
                full = e.t
    assert full is not None and early
    assert max(early) < full, (early, full)


def _early_errors(rec: dict[str, Any], keep: Any, cfg: PipelineConfig) -> list[tuple[float, float]]:
    """(measured 30 deg heading p95, its predicted bound) of each early calibration of the kept samples."""
    cal, out = SensorCalibrator("mag", cfg), []
    for t, v in zip(rec["t"][keep].tolist(), rec["xyz"][keep].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and cal._partial is not None and cal._partial.figures is not None:
                c = e.calibration
                out.append((INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0),
                            cal._partial.figures.tilt30_deg))
    return out


def test_an_early_fit_takes_no_block_across_dropped_samples(monkeypatch: pytest.MonkeyPatch) -> None:
    """Half the samples never arrive (those with a large x: as if dropped as out of range): a block mean of the recent
    samples across such a gap is a chord's, inside the sphere. With early fits published at 2.5 deg, seed 102 published
    one 3.98 deg off at 30 deg for a 1.62 deg bound; such blocks are now left out (``_early_blocks``)."""
    import dataclasses

    from ros_margcal.model.fitting_geometric import block_means

    rec = INDEPENDENT.generate("mag", "tumble", duration_s=12.0, rate_hz=50.0, seed=102, hard_iron_mag=30e-6,
                               symmetric_soft_iron=True)
    keep = np.abs(rec["xyz"][:, 0]) <= 0.5 * np.abs(rec["xyz"][:, 0]).max()
    cfg = dataclasses.replace(PipelineConfig.for_sensor("mag"), early_heading_p95_deg=2.5)
    errors = _early_errors(rec, keep, cfg)
    assert errors and all(err <= bound for err, bound in errors), errors
    monkeypatch.setattr(PartialCalibration, "_early_blocks",
                        lambda self: block_means(self._recent_v, -(-len(self._recent_v) // self.EARLY_POINTS)))
    assert any(err > 2.0 * bound for err, bound in _early_errors(rec, keep, cfg))  # the blocks before



def test_regions_seen_counts_the_parts_of_the_sphere_a_fit_saw() -> None:
    """All directions: every one of the 12 regions (about 63 deg across); a cap of 40 deg about +z, which lies between
    two of their centres: at most four."""
    from ros_margcal.model.calibration import Calibration
    from ros_margcal.stream.observable import regions_seen

    rng = np.random.default_rng(5)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    cal = Calibration(np.array([1.0, -2.0, 0.5]), 2.0 * np.eye(3), norm=1.0)
    raw = u / 2.0 + cal.offset  # W (raw - b) = u
    assert regions_seen(cal, raw) == 12
    assert regions_seen(cal, raw[u[:, 2] > np.cos(np.radians(40.0))]) <= 4
    assert regions_seen(cal, raw[:2]) == 0  # fewer than REGION_MIN_POINTS anywhere


def test_a_tumble_is_published_at_the_partial_standard_once_it_saw_half_the_sphere() -> None:
    """Seed 41 of ``bench_speed.py``'s tumble at 50 Hz: its first calibration is published with a 30 deg bound between
    ``early_heading_p95_deg`` and ``max_heading_p95_deg`` (before: 1 deg, at 8 s), its directions in at least
    ``RICH_REGIONS`` regions, within its bound; early fits then refine it to 1 deg."""
    from ros_margcal.stream.observable import RICH_REGIONS, regions_seen

    rec = INDEPENDENT.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=41, gyro_scale=0.03,
                               hard_iron_mag=30e-6, symmetric_soft_iron=True)
    cfg = PipelineConfig.for_sensor("mag")
    cal, out = SensorCalibrator("mag", cfg), []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and cal._partial is not None and cal._partial.figures is not None:
                c = e.calibration
                out.append((t, INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0),
                            cal._partial.figures.tilt30_deg, regions_seen(c, cal._early_blocks()[0])))
        if t > 8.0:
            break
    assert out, "nothing published in 8 s"
    t0, err0, bound0, regions0 = out[0]
    assert t0 < 6.0
    assert cfg.early_heading_p95_deg < bound0 <= cfg.max_heading_p95_deg
    assert regions0 >= RICH_REGIONS and err0 <= bound0
    assert min(bound for _, _, bound, _ in out) <= cfg.early_heading_p95_deg
    assert all(err <= bound for _, err, bound, _ in out)


def test_a_real_fit_over_part_of_the_sphere_waits_for_the_early_standard(real_recording: Any) -> None:
    """The sunsided HMC5883L: the series fit of its first 18.5 s (directions in 5 of 12 regions) has a 2.24 deg bound
    at 30 deg and is 3.03 deg from the whole recording's batch fit. Published at 2.5 deg it was a miss; it now waits."""
    from ros_margcal.recordings.read import read_recording

    rec = read_recording(real_recording("sunsided_hmc5883l_full_sphere_mag.csv"), sensor="mag")
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", "gauss"))
    first, notes = None, set()
    for t, v in zip(np.asarray(rec.t).tolist(), np.asarray(rec.raw, dtype=np.float64).tolist(), strict=True):
        if any(e.kind is EventKind.CALIBRATED for e in cal.push(t, v)):
            first = t
            break
        notes.add(cal._partial_note)
        if t > 20.0:
            break
    assert first is None or first > 20.0, first
    held = [n for n in notes if re.search(r"regions < 7\) (\d+\.\d+) deg > 1 deg", n)]
    assert any(float(re.search(r"< 7\) (\d+\.\d+) deg", n).group(1)) <= 2.5 for n in held), notes  # the rule held it


def test_a_tumble_whose_tilt_seen_stays_at_45_deg_is_not_taken_for_a_ring() -> None:
    """Seed 45 of ``bench_speed.py``'s tumble at 50 Hz: its early fits see a tilt of 44-45 deg while their directions
    fill 7-9 of the 12 regions. Judged as a ring's they were refused for the azimuths turned through (72 %, 75 %) and the
    first calibration came at 8.56 s; as rich motion (``RICH_REGIONS``) at 4.56 s, within its bound."""
    rec = INDEPENDENT.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=45, gyro_scale=0.03,
                               hard_iron_mag=30e-6, symmetric_soft_iron=True)
    cal, out = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and cal._partial is not None and cal._partial.figures is not None:
                c = e.calibration
                out.append((t, INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0),
                            cal._partial.figures.tilt30_deg, cal._partial.tilt_seen_deg))
        if t > 6.0:
            break
    assert out, "nothing published in 6 s"
    t0, _, _, tilt0 = out[0]
    assert t0 < 5.0 and tilt0 <= PipelineConfig.for_sensor("mag").partial_max_tilt_deg
    assert all(err <= bound for _, err, bound, _ in out), out


def test_an_early_fit_at_100_hz_sees_ten_seconds() -> None:
    """Tuning seed 43 of ``bench_speed.py``'s tumble at 100 Hz: the 500 recent samples hold 5 s, and early fits of 5 s
    stayed in 5-6 of the 12 regions (first good calibration at 9.99 s; 6.06 s at 50 Hz). An early fit takes the last
    ``EARLY_SPAN_S`` of samples when they are more than the recent ones (up to twice as many): 7.03 s, nothing
    published worse than 5 deg; at 50 Hz the same 500 samples as before."""
    rec = INDEPENDENT.generate("mag", "tumble", duration_s=60.0, rate_hz=100.0, seed=43, gyro_scale=0.03,
                               hard_iron_mag=30e-6, symmetric_soft_iron=True)
    cal, good, widest = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), None, (0, 0.0)
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED:
                c = e.calibration
                err = INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0)
                assert err <= 5.0, (t, err)  # no wrong acceptance (bench_speed.py's standard)
                good = good if good is not None or err > 1.0 else t
        if cal._early_open() and len(cal._early_t):  # the window an early fit would read now: all of the last 10 s
            stamps, samples = cal._early_window()
            assert len(samples) <= 2 * cal.config.recent_samples
            assert stamps[-1] - stamps[0] >= min(t - rec["t"][0], cal.EARLY_SPAN_S) - 0.02, (t, stamps[0])
            widest = max(widest, (len(samples), float(stamps[-1] - stamps[0])))
        if t > 12.0:
            break
    assert good is not None and good < 8.0, good
    assert widest[0] > cal.config.recent_samples, widest  # more than the recent samples (5 s here): 7 s when it passed
    for rate, n in ((50.0, 500), (100.0, 1000), (200.0, 1000)):  # 15 s still, uncalibrated: early fits stay open
        still = SensorCalibrator("mag", PipelineConfig.for_sensor("mag"))
        noise = np.random.default_rng(int(rate)).normal(scale=0.1e-6, size=(int(15 * rate), 3))
        for k, v in enumerate(np.array([20e-6, -5e-6, 40e-6]) + noise):
            still.push(k / rate, v)
        stamps, samples = still._early_window()
        assert still._early_open() and len(samples) == n, (rate, len(samples))
        if rate == 50.0:
            assert samples == list(still._recent_v)  # at 50 Hz the recent samples, as before
        else:
            assert stamps[-1] - stamps[0] == pytest.approx(min(10.0, (n - 1) / rate), abs=1e-9)


def test_a_tumble_whose_first_seconds_turn_about_no_one_axis_is_judged_as_rich_motion() -> None:
    """Seed 84 of ``bench_speed.py``'s tumble at 50 Hz: its early fits at 2 and 4 s, tilted 20-40 deg, saw the field
    turn through 36 % of the azimuths about the body z axis and were refused as no ground robot's turns; the first
    calibration came at 8 s. An early fit tilted past a ring's is now judged as rich motion's (at 30 deg, on the early
    standard): one at 6 s is published, within its bound and within 1 deg at 30 deg."""
    rec = INDEPENDENT.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=84, gyro_scale=0.03,
                               hard_iron_mag=30e-6, symmetric_soft_iron=True)
    cal, out, notes = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), [], set()
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and cal._partial is not None and cal._partial.figures is not None:
                c = e.calibration
                out.append((t, INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0),
                            cal._partial.figures.tilt30_deg))
        notes.add(cal._partial_note)
        if t > 7.0:
            break
    assert any("(not a ground robot's turns), judged as rich motion" in n for n in notes), notes
    assert out, "nothing published in 7 s"
    assert out[0][0] < 7.0 and out[0][1] <= 1.0, out  # 6.1 s (8.1 s before)
    assert all(err <= bound for _, err, bound in out), out
