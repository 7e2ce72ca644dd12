"""Study: the streaming calibrator on a magnetometer whose x axis saturates, with and without the saturated
samples dropped (``drop_saturated``, ``stream/saturation.py``; the baseline is the same run with it off).

The independent generator's tumble (120 s at 50 Hz, 30 uT hard iron), its x axis clipped at ``--clip`` uT (the
sensor's range); per seed the share of samples beyond it, the samples dropped as saturated, the first calibration,
the worst 30 deg heading p95 of any published calibration and the final one's (against the generator's truth).
Seeds 21-23 were looked at while the rule was written (``--seeds 21-24``); 24-33 were not (the default).
``--overflow``: beyond the range the axis reads ``OVERFLOW_UT`` instead, whatever the sign (an HMC5883L's overflow
code).

    python scripts/study_saturation.py [--clip 40] [--seeds 24-34] [--overflow]
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np
from study_ground_robot import independent_generator  # scripts/ is on the path when a script in it runs

from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

OVERFLOW_UT = -4096 / 1090 * 100.0
"""An HMC5883L's overflow code, -4096 counts, at its default gain of 1090 LSB/G, in uT (-375.8)."""


def run(gen: Any, seed: int, clip_t: float, drop: bool, overflow: bool = False) -> dict[str, float]:
    rec = gen.generate("mag", "tumble", duration_s=120.0, rate_hz=50.0, seed=seed, hard_iron_mag=30e-6,
                       symmetric_soft_iron=True)
    x = np.array(rec["xyz"], dtype=np.float64)
    out = np.abs(x[:, 0]) > clip_t
    beyond = float(np.mean(out))
    x[:, 0] = np.clip(x[:, 0], -clip_t, clip_t)
    if overflow:
        x[out, 0] = OVERFLOW_UT * 1e-6
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", drop_saturated=drop))
    first, p95 = math.inf, []
    for t, v in zip(rec["t"].tolist(), x, strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and e.calibration is not None:
                first = min(first, t)
                p95.append(gen.heading_p95(e.calibration.matrix, e.calibration.offset, rec["truth"], tilt_deg=30.0))
    final = (gen.heading_p95(cal.calibration.matrix, cal.calibration.offset, rec["truth"], tilt_deg=30.0)
             if cal.calibration is not None else math.nan)
    return {"beyond": beyond, "saturated": float(cal.dropped["saturated"]), "first": first,
            "worst": max(p95, default=math.nan), "final": final}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", type=float, default=40.0, help="the x axis's range, uT (default 40)")
    ap.add_argument("--seeds", default="24-34", help="A-B: seeds A..B-1 (default 24-34, not looked at)")
    ap.add_argument("--overflow", action="store_true", help=f"beyond the range the axis reads {OVERFLOW_UT:.1f} uT")
    a = ap.parse_args(argv)
    try:
        lo, hi = (int(s) for s in a.seeds.split("-"))
    except ValueError:
        ap.error(f"--seeds: expected A-B, got {a.seeds!r}")
    if not (0 < a.clip < 1e3 and 0 <= lo < hi):
        ap.error("--clip must lie in (0, 1000) uT and --seeds A-B have A < B")
    gen = independent_generator()
    what = f"reads {OVERFLOW_UT:.1f} uT beyond +-{a.clip:g} uT" if a.overflow else f"clipped at +-{a.clip:g} uT"
    print(f"tumble 120 s at 50 Hz, 30 uT hard iron, x {what}; 30 deg heading p95 (deg) against the "
          "truth; dropped: drop_saturated true (the default), kept: false (the code before it)")
    print(f"  {'seed':>4s} {'beyond':>7s} {'dropped':>8s} | {'first s':>7s} {'worst':>6s} {'final':>6s} | "
          f"{'kept: first s':>13s} {'worst':>6s} {'final':>6s}")
    for seed in range(lo, hi):
        new, old = (run(gen, seed, a.clip * 1e-6, drop, a.overflow) for drop in (True, False))
        print(f"  {seed:4d} {100 * new['beyond']:6.1f}% {new['saturated']:8.0f} | {new['first']:7.1f} {new['worst']:6.2f} "
              f"{new['final']:6.2f} | {old['first']:13.1f} {old['worst']:6.2f} {old['final']:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
