"""A partial fit's heading figures computed when first read (issue 28 item 3): the values the eager computation
gave, no figure computed that nobody reads, and a status that reads one never raises."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros_margcal.model import heading
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_core import parameter_names
from ros_margcal.stream import observable

NAMES = parameter_names("sym", scale_free=False)


def _cal() -> Calibration:
    sd = np.array([1e-7] * 3 + [1e-3] * 6)
    return Calibration(np.array([5e-6, -3e-6, 1e-6]), np.eye(3), norm=48e-6,
                       covariance=np.diag(sd * sd), parameter_names=NAMES)


def test_figures_equal_the_eager_ones_and_wait_to_be_read(monkeypatch: pytest.MonkeyPatch) -> None:
    """Nothing is computed until read; then each figure is heading_p95_quantile's / _typical's, once."""
    calls: list[float] = []
    real = heading.heading_p95_quantile

    def counted(cal: Calibration, **kw: float) -> float:
        calls.append(kw["tilt_deg"])
        return real(cal, **kw)

    monkeypatch.setattr(observable, "heading_p95_quantile", counted)
    cal = _cal()
    figs = observable._figures(cal, 55.0)
    assert calls == []
    assert figs.tilt30_deg == real(cal, tilt_deg=30.0, inclination=55.0)
    assert figs.tilt30_deg == figs.tilt30_deg and calls == [30.0]  # kept
    assert figs.level_deg == real(cal, tilt_deg=0.0, inclination=55.0)
    assert figs.level_typical_deg == heading.heading_p95_typical(cal, tilt_deg=0.0, inclination=55.0)
    assert 0.0 < figs.level_deg < heading.UNDETERMINED_DEG and 0.0 < figs.tilt30_deg < heading.UNDETERMINED_DEG


def test_no_covariance_is_refused_at_once() -> None:
    """A calibration without the symmetric covariance fails when the figures are made, not when a status reads them."""
    with pytest.raises(InputError, match="covariance over"):
        observable._figures(_cal().replace(covariance=None, parameter_names=()), 60.0)


def test_a_figure_that_cannot_be_computed_reads_not_determined(monkeypatch: pytest.MonkeyPatch) -> None:
    """A covariance not finite, or a computation that fails when a status reads it: NaN, shown as 'not determined',
    never a traceback in the status."""
    cov = np.full((9, 9), np.inf)
    figs = observable._figures(_cal().replace(covariance=cov), 60.0)
    assert math.isnan(figs.level_deg) and math.isnan(figs.tilt30_typical_deg)

    def fails(cal: Calibration, **kw: float) -> float:
        raise np.linalg.LinAlgError("singular")

    monkeypatch.setattr(observable, "heading_p95_quantile", fails)
    figs = observable._figures(_cal(), 60.0)
    assert heading.format_bound(figs.tilt30_deg) == "not determined"
