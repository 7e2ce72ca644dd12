"""A ring's or band's refit is judged against the current partial calibration at the same tilt.

The predicted heading p95 of a partial fit is taken at the tilt its data show; a refit on more data usually shows
more tilt, and its figure there is higher for that reason alone. Compared at different tilts, a refit of a +-20 deg
band with 50 % more data (0.91 deg at 16.6 deg against the current's 0.90 deg at 13.4 deg) was refused, and the
first calibration, 4 deg off at 30 deg of tilt, stayed until 33 s (39 s on the 120 s recording) instead of 26 s.
Found on seed 35 of ``bench_speed.py``'s band (the seed this was made on).
"""

from __future__ import annotations

from typing import Any

import pytest
from conftest import INDEPENDENT

import ros_margcal.stream.partial as partial_module
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

REAL = partial_module.partial_fit_steps


@pytest.fixture(scope="module")
def band() -> dict[str, Any]:
    return INDEPENDENT.generate("mag", "band", duration_s=45.0, rate_hz=50.0, band_deg=20.0, seed=35,
                                gyro_scale=0.03, hard_iron_mag=30e-6, symmetric_soft_iron=True)


def _published(rec: dict[str, Any]) -> list[tuple[float, float]]:
    """(stamp, measured 30 deg heading p95) of each published calibration, the gyro's rates pushed too."""
    cal, out = SensorCalibrator("mag", PipelineConfig.for_sensor("mag")), []
    for t, v, w in zip(rec["t"].tolist(), rec["xyz"].tolist(), rec["gyro"].tolist(), strict=True):
        for e in cal.push(t, v, w):
            if e.kind is EventKind.CALIBRATED:
                c = e.calibration
                out.append((e.t, INDEPENDENT.heading_p95(c.matrix, c.offset, rec["truth"], 30.0)))
    return out


def test_a_refit_showing_more_tilt_is_compared_at_the_current_tilt(band: dict[str, Any],
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    pubs = _published(band)
    assert len(pubs) >= 2 and pubs[0][1] > 3.0  # the first: 4.4 deg off at 30 deg
    assert pubs[1][0] < 30.0 and pubs[1][1] < 1.5  # replaced at 26 s (0.90 deg)

    def unlike(series: Any, *args: Any, **kw: Any) -> Any:  # the rule before: each at its own tilt
        return (yield from REAL(series, *args, **{**kw, "current_tilt": None}))

    monkeypatch.setattr(partial_module, "partial_fit_steps", unlike)
    before = _published(band)
    assert before[0] == pubs[0]
    assert len(before) == 1 or before[1][0] > 30.0  # kept until 33 s
