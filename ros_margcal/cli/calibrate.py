"""``margcal calibrate INPUT``: fit a calibration to a CSV or rosbag2 recording.

Examples::

    margcal calibrate mag.csv --sensor mag --model sym -o calib.yaml
    margcal calibrate run.mcap --sensor accel --norm 9.80665 --json fit.json
    margcal calibrate mag.csv --method lin_auto --model diag
    margcal calibrate disturbed.mcap --sensor mag --loss huber

When the requested fit fails (does not converge, degenerate data) or its result is implausible (the
online calibrator's limits: field norm in a known unit, parameter uncertainty, offset, gains), the
command says why and fits what the data allow (``fit_rescue``): nothing on a static recording (exit
code 3), one calibration per side of a located offset change, or the prior fit on partial coverage
(which parameters were updated, which are from the prior), with the predicted heading error for a
magnetometer. ``--no-rescue`` keeps the old behaviour (the error).

Before the fit, readings no fit should see are dropped, counted and said (``fit_rescue.screen``): a
component beyond ``fit_rescue.MAX_READING`` (not a reading in any unit), and spikes, readings far
beyond every other one from their median (``--keep-spikes`` fits them). A clock that goes back (a
logger restart) keeps the recording in file order: the ellipsoid does not depend on time, and the
stamps before each restart are moved back to run on into the last clock, for the gate, the change
search and the calibration's stamp (``recordings.continue_clock``). ``--norm`` must be within
``NORM_RATIO`` of the readings' scale (the output unit may differ from the raw one, but not by
10^300), ``--f-scale`` of ``--norm``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..coverage.gate import InactivityGate
from ..model.calibration import MODELS, Calibration
from ..model.calibration_file import save_calibrations
from ..model.errors import ConfigError, ConvergenceError, DegenerateDataError, RecordingError
from ..model.fitting import LOSSES, METHODS, SUPPORTED, fit
from ..recordings.read import read_recording
from ..recordings.recording import Recording, continue_clock
from .fit_rescue import MIN_SCALE, Rescue, check, config_for, heading_text, reading_scale, rescue, residual_note, screen

__all__ = ["NORM_RATIO", "register", "run", "still_samples"]

_DEFAULT_MODEL = {"sphere": "eye", "lin_auto": "diag"}

NORM_RATIO = 1e12
"""``--norm`` over the readings' scale (``fit_rescue.reading_scale``), and ``--f-scale`` over ``--norm`` (or that scale),
must lie within [1 / NORM_RATIO, NORM_RATIO]:
every unit conversion (tesla to counts, m/s² to mg) is well inside, and beyond it the fitted matrix's
products over- or underflow."""


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    combos = "; ".join(f"{m}: {', '.join(ms)}" for m, ms in SUPPORTED.items())
    p = subparsers.add_parser(
        "calibrate",
        help="fit offset and matrix to a recording (CSV or rosbag2), print them with uncertainties, write YAML",
        description=f"Fit a magnetometer or accelerometer calibration to a recording. Models per method: {combos}.",
    )
    p.add_argument("input", type=Path, help="recording: .csv (t,x,y,z[,temp,gx,gy,gz]), .mcap, .db3 or a rosbag2 directory")
    p.add_argument(
        "--sensor",
        choices=("mag", "accel"),
        default=None,
        help="which sensor to read (bags: MagneticField or Imu); default: guessed from the file",
    )
    p.add_argument("--topic", default=None, help="bag topic to read when several match")
    p.add_argument(
        "--model",
        choices=MODELS,
        default=None,
        help="eye (offset + scale), diag (+ gains), sym (+ cross terms); default sym (eye: sphere, diag: lin_auto)",
    )
    p.add_argument("--method", choices=METHODS, default="lm", help="fitting method (default lm)")
    p.add_argument(
        "--norm",
        type=float,
        default=None,
        help="reference norm in output units (e.g. 9.80665 for m/s^2); default: estimate it, det(W) = 1",
    )
    p.add_argument("--loss", choices=LOSSES, default="linear", help="robust loss for outliers such as disturbances (lm only)")
    p.add_argument("--f-scale", type=float, default=None, help="robust loss scale in output units (default: from the residuals)")
    p.add_argument(
        "--samples",
        choices=("auto", "all", "still"),
        default="auto",
        help="which samples to fit: all, or still ones (accelerometer inactivity gate, 2 s, CV 3e-3); "
        "auto = still for accel, all for mag",
    )
    p.add_argument("--unit", default=None, help="unit of the calibrated output (default: the recording's unit)")
    p.add_argument("-o", "--output", type=Path, default=None, help="write the calibration as ros__parameters YAML")
    p.add_argument("--json", type=Path, default=None, help="write the result (parameters, std, stats) as JSON")
    p.add_argument("--keep-spikes", action="store_true",
                   help="fit every reading, also spikes far beyond all others from their median (dropped by default)")
    p.add_argument("--no-rescue", action="store_true",
                   help="when the fit fails or is implausible, stop with the error instead of diagnosing why "
                   "and fitting what the data determine (static: nothing; a change: each side; partial: the prior fit)")
    p.set_defaults(func=run)  # fmt: skip


def still_samples(rec: Any) -> np.ndarray:
    """Averaged still samples of an accelerometer stream through the inactivity gate (Gietzelt Sec. 2.4)."""

    gate = InactivityGate()
    out = []
    gyro = rec.gyro
    for i in range(len(rec.t)):
        avg = gate.push(rec.t[i], rec.raw[i], None if gyro is None else gyro[i])
        if avg is not None:
            out.append(avg)
    if not out:
        msg = "no still periods found in the recording (inactivity gate: 2 s window, CV 3e-3); use --samples all"
        raise RecordingError(msg)
    return np.asarray(out, dtype=np.float64)


def result_dict(cal: Calibration, source: str, n_read: int) -> dict[str, Any]:
    """The fit as plain JSON types: calibration fields, one-sigma uncertainties, residual statistics."""
    d = cal.to_dict()
    d.pop("covariance", None)
    d["std"] = cal.parameter_std()
    d["input"] = source
    d["samples_read"] = n_read
    return d


def _print(cal: Calibration, source: str, n_read: int) -> None:
    std = cal.parameter_std()
    unit = f" {cal.unit}" if cal.unit else ""
    print(f"{cal.sensor or 'sensor'} calibration of {source}: model {cal.model}, method {cal.method}, "
          f"{cal.stats.n_points if cal.stats else '?'} of {n_read} samples")  # fmt: skip
    fixed = " (the prior's, fixed)" if cal.method == "map" else " (given)"
    print(f"  norm     {cal.norm:.6g}{unit}" + (f" +- {std['norm']:.2g}" if "norm" in std else fixed))
    for i, axis in enumerate("xyz"):
        s = std.get(f"b_{axis}")
        print(f"  offset {axis} {cal.offset[i]:>13.6g}" + (f" +- {s:.2g}" if s is not None else ""))
    print("  matrix W (calibrated = W (raw - offset)):")
    for i, axis in enumerate("xyz"):
        row = "".join(f"{cal.matrix[i, j]:>13.6g}" for j in range(3))
        sd = [std.get(f"w_{min(axis, b)}{max(axis, b)}", std.get("w")) for b in "xyz"]
        sds = "".join(f"{'' if s is None else f'+-{s:.2g}':>11}" for s in sd)
        print(f"    {row}    {sds}".rstrip())
    if cal.covariance is None:
        print("  (no covariance: method mvee is not a least-squares fit, or too few points)")
    if cal.stats is not None:
        st = cal.stats
        print(f"  residual |W (v - b)| - norm: rms {st.rms:.4g}{unit} ({100 * st.rms_relative:.3g} % of the norm), "
              f"max {st.max_abs:.4g}{unit}, iterations {st.iterations}")  # fmt: skip


def _in_file_order(rec: Recording) -> Recording:
    """The recording with a clock that goes back (a logger restart) made one clock (``continue_clock``), said once."""
    times, back = continue_clock(rec.t)
    if back.size:
        i = int(back[0])
        print(f"time goes back at {back.size} place(s), first after sample {i} ({rec.t[i]:.6g} -> {rec.t[i + 1]:.6g} s: "
              "a logger restart?): the readings are fitted in file order, the stamps before each restart moved back to "
              "run on into the last clock", file=sys.stderr)
        rec = rec.slice(slice(None))
        rec.t = times
    return rec


def _check_scales(norm: float | None, f_scale: float | None, points: np.ndarray) -> None:
    """The readings' scale must be one the fit can square; ``--norm`` and ``--f-scale`` within ``NORM_RATIO`` of it
    (``--f-scale`` of ``--norm`` when given: it is in output units)."""
    scale = reading_scale(points)
    if 0.0 < scale < MIN_SCALE:
        msg = (f"the readings are of the order of {scale:.3g}: too small to fit (below {MIN_SCALE:g}); "
               "give them in another unit")
        raise RecordingError(msg)
    if not scale > 0.0:
        return  # no scale to judge by: the fit refuses the data as degenerate
    good = norm is not None and math.isfinite(norm) and norm > 0.0
    for name, value, ref, of in (("--norm", norm, scale, "the readings' scale"),
                                 ("--f-scale", f_scale, norm if good else scale, "--norm" if good else "the readings' scale")):
        if value is None or not math.isfinite(value) or value <= 0.0 or ref is None:
            continue  # absent, or the fit's own check of the value (positive, finite)
        if not 1.0 / NORM_RATIO <= value / ref <= NORM_RATIO:
            what = ("the reference norm of the calibrated output in its unit (e.g. 9.80665 for m/s^2, 5e-05 for a "
                    "field in tesla) or omit it") if name == "--norm" else "a residual scale in output units or omit it"
            msg = f"{name} {value:g} is not within a factor {NORM_RATIO:g} of {of} ({ref:.4g}); give {what}"
            raise ConfigError(msg)


def run(args: argparse.Namespace) -> int:
    """Read the recording, fit, print, write YAML/JSON; returns the exit code."""

    rec = read_recording(args.input, sensor=args.sensor, topic=args.topic, order="file")
    n_read, last_stamp = len(rec.t), float(rec.t[-1]) if len(rec.t) else None
    rec = _in_file_order(rec)
    sensor = args.sensor or rec.sensor or ""
    use_still = args.samples == "still" or (args.samples == "auto" and sensor == "accel")
    absurd = screen(rec.raw, spikes=False)  # before the gate: its windows would average them in
    if absurd.absurd:
        print(absurd.text(), file=sys.stderr)
        rec = rec.slice(absurd.keep)
    points = still_samples(rec) if use_still else np.asarray(rec.raw, dtype=np.float64)
    if use_still:
        print(f"inactivity gate: {len(points)} still samples from {len(rec.t)} readings", file=sys.stderr)
    times = None if use_still or rec.t is None else np.asarray(rec.t, dtype=np.float64)
    unit = args.unit if args.unit is not None else (rec.unit or "")
    far = screen(points, spikes=not args.keep_spikes)
    if far.spikes:
        print(far.text(unit), file=sys.stderr)
        points = points[far.keep]
        times = None if times is None else times[far.keep]
    _check_scales(args.norm, args.f_scale, points)
    dropped = {**absurd.dropped, **far.dropped}
    extra: dict[str, Any] = {"dropped": dropped} if dropped else {}
    model = args.model or _DEFAULT_MODEL.get(args.method, "sym")
    cfg = config_for(sensor, unit) if sensor in ("mag", "accel") else None
    try:
        cal = fit(points, model=model, method=args.method, norm=args.norm, loss=args.loss, f_scale=args.f_scale,
                  sensor=sensor, unit=unit)  # fmt: skip
        failure = check(cal, cfg)
        high = residual_note(cal, cfg)
    except (ConvergenceError, DegenerateDataError) as exc:
        if args.no_rescue:
            raise
        cal, failure, high = None, str(exc), ""
    if (failure or high) and not args.no_rescue:
        res = rescue(times, points, failure=failure or high, model=model if model in SUPPORTED["lm"] else "sym",
                     norm=args.norm, loss=args.loss, sensor=sensor, unit=unit, cfg=cfg, change_only=not failure)
        if res is not None:
            return _report_rescue(res, args, sensor, n_read, extra)
    for note in (failure, high):
        if note:
            print(f"warning: {note}" + ("" if failure else " (no offset change located: motion or disturbances?)"),
                  file=sys.stderr)
    assert cal is not None
    if last_stamp is not None:
        cal = cal.replace(stamp=last_stamp)
    _print(cal, str(args.input), n_read)
    _write(args, {sensor or "sensor": cal}, [{**result_dict(cal, str(args.input), n_read), **extra}])
    return 0


def _write(args: argparse.Namespace, cals: dict[str, Calibration], results: list[dict[str, Any]]) -> None:
    if args.output is not None:
        path = save_calibrations(args.output, cals)
        print(f"wrote {path}")
    if args.json is not None:
        d = results[0] if len(results) == 1 else {"calibrations": results}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(d, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")


def _report_rescue(res: Rescue, args: argparse.Namespace, sensor: str, n_read: int, extra: dict[str, Any]) -> int:
    """Print the diagnosis and the calibrations it fitted, write them; 3 when nothing could be fitted."""
    for line in res.lines:
        print(line)
    if res.refused:
        return 3
    cals: dict[str, Calibration] = {}
    results = []
    key = sensor or "sensor"
    last = max((k for k, p in enumerate(res.parts) if p.calibration is not None), default=-1)
    for k, part in enumerate(res.parts):
        cal = part.calibration
        print(f"-- {part.label}: {part.n_points} samples" + (f" ({part.note})" if part.note else ""))
        if cal is None:
            continue
        _print(cal, str(args.input), n_read)
        pf = part.prior_fit
        if pf is not None:
            print(f"  updated by the data: {', '.join(pf.updated) or 'none'}")
            print(f"  from the prior:      {', '.join(pf.from_prior) or 'none'}")
        if sensor == "mag":
            text = heading_text(cal)
            if text:
                print(f"  {text}")
        name = key if k == last else f"{key}_{k + 1}"  # the last calibration is the sensor's current one
        cals[name] = cal
        d = {**result_dict(cal, str(args.input), n_read), **extra}
        d["diagnosis"] = res.kind
        d["part"] = part.label
        if pf is not None:
            d["updated"], d["from_prior"] = list(pf.updated), list(pf.from_prior)
        results.append(d)
    _write(args, cals, results)
    return 0
