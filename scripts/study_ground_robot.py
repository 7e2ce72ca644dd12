"""Study: the observability-aware MAP fit on a ground robot, on data the package did not generate.

A magnetometer on a robot turning in yaw with small roll and pitch (tests/independent/generator.py,
motion "ground"), 30 uT hard iron, a few per cent symmetric soft iron, white plus coloured noise. For
each case: the MAP fit from the broad prior (``model.fitting_prior``) on the time series, the measured
heading p95 (the generator's truth model, level and at +-30 deg tilt) against the predicted one
(``model.heading``), and which parameters the data updated.

Seeds 1-3 and 11-13 were used while designing the fit; seeds 100-109 were not, and are reported
separately. Run: ``python scripts/study_ground_robot.py [--seconds 300] [--quick]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

from ros_margcal.model.fitting_prior import broad_prior, fit_with_prior
from ros_margcal.model.heading import heading_p95, inclination_deg

TUNING = (1, 2, 3, 11, 12, 13)
HELD_OUT = tuple(range(100, 110))


def independent_generator() -> ModuleType:
    """tests/independent/generator.py, loaded by path (the scripts share this loader)."""
    path = Path(__file__).resolve().parents[1] / "tests" / "independent" / "generator.py"
    spec = importlib.util.spec_from_file_location("margcal_independent_generator", path)
    if spec is None or spec.loader is None:
        sys.exit(f"cannot load the independent generator from {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def case(gen, seed: int, tilt: float, seconds: float) -> dict[str, float]:
    """One ground-robot recording: fit, measured and predicted heading p95, share of parameters updated."""
    rec = gen.generate("mag", "ground", duration_s=seconds, rate_hz=50.0, seed=seed, tilt_deg=tilt,
                       symmetric_soft_iron=True)
    tr = rec["truth"]
    pts = rec["xyz"][::10]
    pf = fit_with_prior(pts, broad_prior(pts, tr["norm"]), time_ordered=True)
    cal = pf.calibration
    inc = inclination_deg(cal, pts)
    return {
        "level": gen.heading_p95(cal.matrix, cal.offset, tr, tilt_deg=0.0),
        "level_pred": heading_p95(cal, tilt_deg=0.0, inclination=inc),
        "tilt30": gen.heading_p95(cal.matrix, cal.offset, tr, tilt_deg=30.0),
        "tilt30_pred": heading_p95(cal, tilt_deg=30.0, inclination=inc),
        "offset_xy": float(np.linalg.norm((cal.offset - tr["offset"])[:2]) / tr["norm"]),
        "updated": float(len(pf.updated)),
    }


def main(argv: list[str] | None = None) -> int:
    """Print the table for the tuning and the held-out seeds."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=300.0, help="recording length (default 300 s of turning)")
    p.add_argument("--quick", action="store_true", help="three held-out seeds only")
    args = p.parse_args(argv)
    gen = independent_generator()
    groups = {"tuning": TUNING, "held-out": HELD_OUT[:3] if args.quick else HELD_OUT}
    print(f"{'seeds':9s} {'tilt':>4s}  {'level p95 meas/pred (median)':>29s}  {'30deg p95 meas/pred (median)':>29s}  "
          f"{'worst level':>11s}  {'pred/meas level':>15s}  {'offset xy':>9s}")
    for name, seeds in groups.items():
        for tilt in (5.0, 20.0):
            rows = [case(gen, s, tilt, args.seconds) for s in seeds]
            col = {k: np.array([r[k] for r in rows]) for k in rows[0]}
            ratio = col["level_pred"] / col["level"]
            print(f"{name:9s} {tilt:4.0f}  {np.median(col['level']):13.2f} / {np.median(col['level_pred']):5.2f} deg     "
                  f"{np.median(col['tilt30']):13.2f} / {np.median(col['tilt30_pred']):5.2f} deg     "
                  f"{col['level'].max():8.2f} deg  {ratio.min():6.2f}-{ratio.max():5.2f}x  "
                  f"{100 * np.median(col['offset_xy']):7.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
