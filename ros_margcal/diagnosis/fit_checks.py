"""The recording's calibration fits the diagnosis can trust on part of the sphere.

On a band of tilts (|roll|, |pitch| <= 20 deg) the ellipsoid fit is ill-conditioned: ``lm`` crawls towards a
degenerate ellipsoid, or converges and its second-order bias correction, solved with a near-singular Gram
matrix, lands far off the least-squares optimum (3-8 times the closed form's residual). Features and twins
built on such a fit measure the fit, not the sensor. ``lm_diag`` refuses it (``IllConditionedFit``) so the
caller measures recording and twins with the closed form alike; ``sym_fit`` / ``checked_sym`` fall back on the
algebraic ellipsoid fit (``lin_auto`` fits no cross terms).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.errors import ConvergenceError, MargCalError
from ..model.fitting import fit

__all__ = ["LM_WORSE", "IllConditionedFit", "checked_sym", "closed_form_sym", "lm_diag", "sym_fit"]

Array = NDArray[np.float64]

LM_WORSE = 1.1
"""An ``lm`` fit whose residual RMS exceeds the closed form's by this factor is off the least-squares optimum."""
_MAX_ITER = 400  # LM iterations: strong effects make the ellipsoid fit converge slowly


class IllConditionedFit(ConvergenceError):
    """``lm`` ended off the least-squares optimum (``lm_diag``): the directions, not the data's consistency,
    are the problem, so this is no evidence of an offset change."""


def _rms(cal: Calibration, pts: Array) -> float:
    """RMS of the relative norm residual of ``cal`` on ``pts``."""
    return float(np.sqrt(np.mean((np.linalg.norm(cal.apply(pts), axis=1) / cal.norm - 1.0) ** 2)))


def lm_diag(pts: Array, norm: float | None, *, sensor: str = "", max_iter: int = _MAX_ITER) -> Calibration:
    """The ``diag`` fit by ``lm``, refused when its residual exceeds the closed form's by ``LM_WORSE``.

    See the module docstring: the caller then measures recording and twins with the closed form.

    Raises:
        ConvergenceError: ``lm`` does not converge; ``IllConditionedFit`` when it ends worse than ``lin_auto``.
    """
    cal = fit(pts, model="diag", method="lm", norm=norm, sensor=sensor, max_iter=max_iter)
    try:
        closed = fit(pts, model="diag", method="lin_auto", norm=norm, sensor=sensor)
    except MargCalError:
        return cal
    ratio = _rms(cal, pts) / max(_rms(closed, pts), 1e-300)
    if ratio > LM_WORSE:
        msg = (f"lm's diag fit leaves a residual {ratio:.2g} times the closed form's "
               "(directions on part of the sphere make the fit ill-conditioned)")
        raise IllConditionedFit(msg)
    return cal


def closed_form_sym(pts: Array, norm: float | None) -> Calibration:
    """The ``sym`` fit without ``lm``: the algebraic ellipsoid fit (``lin_auto`` fits no cross terms).

    Raises:
        DegenerateDataError: the points do not determine an ellipsoid.
    """
    return fit(pts, model="sym", method="algebraic", norm=norm)


def sym_fit(pts: Array, norm: float | None, closed_form: bool = False) -> Calibration | None:
    """The best (``sym``) fit: ``lm`` (``checked_sym``), or the algebraic fit when ``lm`` fails or with
    ``closed_form`` (``lm`` would run to its iteration limit on the data that needed the closed form);
    None when neither fits."""
    if not closed_form:
        try:
            return checked_sym(fit(pts, model="sym", method="lm", norm=norm, max_iter=_MAX_ITER), pts, norm)
        except MargCalError:
            pass
    try:
        return closed_form_sym(pts, norm)
    except MargCalError:
        return None


def checked_sym(cal: Calibration, pts: Array, norm: float | None) -> Calibration:
    """``lm``'s ``sym`` fit ``cal``, or the algebraic fit when ``cal`` ends worse than it by ``LM_WORSE``
    (the ill-conditioned fit on part of the sphere, see ``lm_diag``)."""
    try:
        alg = closed_form_sym(pts, norm)
    except MargCalError:
        return cal
    return alg if _rms(cal, pts) > LM_WORSE * _rms(alg, pts) else cal
