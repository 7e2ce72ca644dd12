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
10^300), ``--f-scale`` of ``--norm``. Without ``--norm`` an accelerometer in a known unit is fitted with gravity
fixed, as the stream fits it (a fitted norm takes the gains' mean scale: the output would read it at rest).

``--unit`` is the recording's raw unit, checked against the readings or inferred from them
(``raw_units``); all-zero rows are dropped and counted. Whatever is fitted passes the stream's guard
rails before it is written (``calibrate_guard``): otherwise nothing is written and the exit code is
``EXIT_REFUSED`` (4); ``--force`` writes it with the reason in its ``method``. ``--set KEY=VALUE`` sets the
options the guard rails, the gate and the fit use (``CALIBRATE_OPTIONS``; ``set_option``). ``--lat --lon``
take a magnetometer's norm (unless ``--norm``) and the heading figures' inclination from the World Magnetic
Model at that position (``position``). An existing ``-o`` file keeps the other sensors' calibrations (the node's file
holds both; said); one that is no calibration file is refused unless ``--force``. An output that is the recording, lies
inside it or is the other output, or whose folder cannot be written, is refused before the fit (``check_paths``).
Exit codes: 0 written, 2 bad input, 3 nothing to fit (static, too few samples), 4 refused by the guard rails.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..coverage.gate import LEARN_CAP, InactivityGate
from ..model.calibration import MODELS, Calibration
from ..model.calibration_file import read_calibration_file, save_calibrations
from ..model.errors import (
    CalibrationFileError,
    ConfigError,
    ConvergenceError,
    DegenerateDataError,
    RecordingError,
    one_line,
)
from ..model.fitting import LOSSES, METHODS, SUPPORTED, fit
from ..recordings.read import read_recording
from ..recordings.recording import Recording, continue_clock, drop_stamp_glitches
from ..stream.config import PipelineConfig, white_noise
from . import check_paths
from .calibrate_guard import EXIT_REFUSED, forced, norm_source, refusal
from .fit_rescue import (
    MIN_SCALE,
    Rescue,
    check,
    config_for,
    figures_text,
    heading_text,
    inclination_of,
    reading_scale,
    rescue,
    residual_note,
    rests_apart,
    screen,
)
from .position import add_position_args, field_line, position_options, radius_note
from .raw_units import drop_saturated, prepare
from .set_option import SET_HELP, parse_sets, sensor_options

__all__ = ["CALIBRATE_OPTIONS", "NORM_RATIO", "register", "run", "still_samples"]

_DEFAULT_MODEL = {"sphere": "eye", "lin_auto": "diag"}

NORM_RATIO = 1e12
"""``--norm`` over the readings' scale (``fit_rescue.reading_scale``), and ``--f-scale`` over ``--norm`` (or that scale),
must lie within [1 / NORM_RATIO, NORM_RATIO]:
every unit conversion (tesla to counts, m/s² to mg) is well inside, and beyond it the fitted matrix's
products over- or underflow."""


CALIBRATE_OPTIONS = frozenset({"max_iter", "gate_window_s", "gate_cv_threshold", "gate_learn_noise", "max_residual",
                               "max_offset_ratio", "max_offset", "gain_min", "gain_max", "norm_min", "norm_max",
                               "max_parameter_std", "min_points", "max_heading_p95_deg", "drop_saturated",
                               "near_level_tilt_deg", "change_threshold", "heading_inclination_deg", "reference_norm"})
"""The ``--set`` options calibrate uses: the fit's iterations, the accelerometer's gate, the guard rails, the rows on
a saturated axis (``drop_saturated``), a magnetometer's ring held level (``near_level_tilt_deg``, as in the stream),
the offset change a rescue locates (``change_threshold``), the field the heading figures take as given (inclination,
``reference_norm``: also an accelerometer's prior norm). The others are the stream's alone: said, and ignored (not
passed to the limits, whose checks they would fail on)."""

OWN_OPTIONS = {"method": "--method", "loss": "--loss", "model": "--model", "f_scale_rel": "--f-scale",
               "latitude_deg": "--lat", "longitude_deg": "--lon", "altitude_m": "--alt", "field_year": "--date"}
"""Streaming options whose calibrate counterpart is an option of its own (named when --set gives them)."""


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
    p.add_argument("--unit", default=None,
                   help="raw unit of the recording: T, mT, uT, nT, gauss, mG (mag), m/s^2, g, mg (accel), or counts "
                   "(any other name: not checked); refused when the readings are no Earth field or gravity in it. "
                   "Default: a bag's REP-145 unit (T, m/s^2), a CSV's inferred from the readings' size (said)")
    add_position_args(p)
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help=SET_HELP)
    p.add_argument("--force", action="store_true",
                   help="write a calibration the guard rails refuse (offset, gains, field norm, uncertainty, predicted "
                   "heading error); its method records 'forced' and why")
    p.add_argument("-o", "--output", type=Path, default=None, help="write the calibration as ros__parameters YAML")
    p.add_argument("--json", type=Path, default=None, help="write the result (parameters, std, stats) as JSON")
    p.add_argument("--keep-spikes", action="store_true",
                   help="fit every reading, also spikes far beyond all others from their median (dropped by default)")
    p.add_argument("--no-rescue", action="store_true",
                   help="when the fit fails or is implausible, stop with the error instead of diagnosing why "
                   "and fitting what the data determine (static: nothing; a change: each side; partial: the prior fit)")
    p.set_defaults(func=run)  # fmt: skip


def _gated(rec: Any, window: float, cv: float, learn: bool) -> tuple[list[np.ndarray], tuple[float, float], str, float, float]:
    """One pass of the inactivity gate (``window`` s) over ``rec``: the averaged still samples, the quietest window's
    (CV, axis spread) while none passed, what was learnt and the thresholds used. With ``learn`` a first pass learns
    the sensor's rest noise over the whole recording and a second gates with those thresholds, so the still periods
    before the learning settled count too."""
    gyro = rec.gyro
    axis = cv
    learnt = ""
    if learn:
        probe = InactivityGate(window_s=window, cv_threshold=cv, learn=True)
        for i in range(len(rec.t)):
            probe.push(rec.t[i], rec.raw[i], None if gyro is None else gyro[i])
        (cv, axis), learnt = probe.thresholds, probe.learnt
    gate = InactivityGate(window_s=window, cv_threshold=cv, axis_threshold=axis)
    out = []
    quietest = math.inf, math.inf  # the window nearest to still: what a threshold must let through (message below)
    for i in range(len(rec.t)):
        avg = gate.push(rec.t[i], rec.raw[i], None if gyro is None else gyro[i])
        if avg is not None:
            out.append(avg)
        elif not out and max(gate.window_stats) < max(quietest):
            quietest = gate.window_stats
    return out, quietest, learnt, cv, axis


def _poses(samples: list[np.ndarray], apart_deg: float = 10.0) -> int:
    """How many poses still samples hold: directions more than ``apart_deg`` from every pose counted before."""
    poses: list[np.ndarray] = []
    for v in samples:
        u = v / (np.linalg.norm(v) or 1.0)
        if all(float(u @ p) < math.cos(math.radians(apart_deg)) for p in poses):
            poses.append(u)
    return len(poses)


def still_samples(rec: Any, cfg: PipelineConfig | None = None) -> np.ndarray:
    """Averaged still samples of an accelerometer stream through the inactivity gate (Gietzelt Sec. 2.4), with the
    gate options of ``cfg`` (the defaults without; ``gate_learn_noise``: ``_gated``). When none pass, the error says
    what would let them: holds shorter than the window (found with half of it), or the sensor's rest noise."""
    window, given = (2.0, 3e-3) if cfg is None else (cfg.gate_window_s, cfg.gate_cv_threshold)
    learn = cfg is None or cfg.gate_learn_noise
    out, quietest, learnt, cv, axis = _gated(rec, window, given, learn)
    if not out:
        short = _gated(rec, window / 2, given, learn)[0]
        quiet = ""
        poses = _poses(short)
        if poses >= 2:  # still holds in several poses, each shorter than the window (one pose: its noise)
            hint = (f"hold each pose for {window:g} s or more, or --set accel.gate_window_s={window / 2:g} (a {window / 2:g} s "
                    f"window finds {len(short)} still stretches in {poses} poses)")
        elif math.isfinite(max(quietest)):
            need = float(f"{1.5 * max(quietest):.2g}")
            quiet = f"; its quietest window: CV {quietest[0]:.2g}, axis spread {quietest[1]:.2g}"
            if max(quietest) > LEARN_CAP:  # more than a MEMS part at rest is learnt to show: likely a move
                quiet += f", above the {LEARN_CAP:g} a part at rest is learnt to show: was it moving all through?"
            hint = f"--set accel.gate_cv_threshold={need:g} if the sensor lay still that long (its rest noise)"
        else:
            hint = f"--set accel.gate_cv_threshold=... above the sensor's rest noise; no {window:g} s window filled"
        msg = (f"no still periods found in the recording (inactivity gate: {window:g} s window, CV {cv:.2g}, axis "
               f"spread {axis:.2g}{'; ' + learnt if learnt else ''}{quiet}); use --samples all, or {hint}")
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


def _print(cal: Calibration, source: str, n_read: int, fixed: str = "given by --norm") -> None:
    """The calibration with its uncertainties; ``fixed`` says where a norm without one comes from."""
    std = cal.parameter_std()
    unit = f" {cal.unit}" if cal.unit else ""
    print(f"{cal.sensor or 'sensor'} calibration of {source}: model {cal.model}, method {cal.method}, "
          f"{cal.stats.n_points if cal.stats else '?'} of {n_read} samples")  # fmt: skip
    print(f"  norm     {cal.norm:.6g}{unit}" + norm_source(std, fixed))
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
    """The recording with a clock that goes back (a logger restart) made one clock (``continue_clock``), said once;
    a single stamp out of line with its neighbours is a glitch, not a restart: its sample dropped, said."""
    t, (rec, glitches) = rec.t, drop_stamp_glitches(rec)
    if glitches.size:
        i = int(glitches[0])
        print(f"dropped {glitches.size} sample(s) whose stamp is out of line with its neighbours' (first: sample {i}, "
              f"{t[i - 1]:.6g} -> {t[i]:.6g} -> {t[i + 1]:.6g} s)", file=sys.stderr)
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


def _points(rec: Recording, args: argparse.Namespace, cfg: PipelineConfig) -> tuple[np.ndarray, np.ndarray | None,
                                                                                dict[str, int]]:
    """The readings to fit (still samples of an accelerometer), their times (None for still samples) and the
    readings dropped per reason."""
    use_still = args.samples == "still" or (args.samples == "auto" and cfg.sensor == "accel")
    absurd = screen(rec.raw, spikes=False)  # before the gate: its windows would average them in
    if absurd.absurd:
        print(absurd.text(), file=sys.stderr)
        rec = rec.slice(absurd.keep)
    points = still_samples(rec, cfg) if use_still else np.asarray(rec.raw, dtype=np.float64)
    if use_still:
        print(f"inactivity gate: {len(points)} still samples from {len(rec.t)} readings", file=sys.stderr)
    times = None if use_still or rec.t is None else np.asarray(rec.t, dtype=np.float64)
    far = screen(points, spikes=not args.keep_spikes)
    if far.spikes:
        print(far.text(cfg.unit), file=sys.stderr)
        points = points[far.keep]
        times = None if times is None else times[far.keep]
    return points, times, {**absurd.dropped, **far.dropped}


def _prior_norm(args: argparse.Namespace, cfg: PipelineConfig) -> tuple[float | None, str]:
    """The norm a fit holds fixed and where it comes from: --norm, gravity in a known unit, the model field at
    --lat/--lon, else the prior fit's own."""
    if args.norm is not None:
        return args.norm, "given by --norm"
    if cfg.sensor == "accel" and cfg.reference_norm is not None:
        return cfg.reference_norm, f"gravity in {cfg.unit}"
    field = cfg.field_model()
    if field is not None and cfg.reference_norm is not None:
        return cfg.reference_norm, f"{field.model} at --lat/--lon"
    return None, "the readings' sphere radius"


def _existing(args: argparse.Namespace) -> tuple[dict[str, Calibration], str]:
    """The calibrations already in the ``-o`` file (the node's file holds every sensor's) and their node name: the
    other sensors' are kept when it is written, under that name. A file that is no calibration file is refused
    (ConfigError) unless --force, not destroyed."""
    out: Path | None = args.output
    if out is None or not out.is_file():  # none yet; a FIFO or a device the save refuses, naming it
        return {}, "margcal"
    try:
        return read_calibration_file(out)
    except CalibrationFileError as exc:
        if not args.force:
            msg = (f"-o {out} exists and is no calibration file ({one_line(exc)}); choose another file, or --force "
                   "to replace it")
            raise ConfigError(msg) from exc
        print(f"warning: -o {out} is no calibration file ({one_line(exc)}): replaced (--force)", file=sys.stderr)
        return {}, "margcal"


def _used_options(overrides: dict[str, Any]) -> dict[str, Any]:
    """The ``--set`` options calibrate uses (``CALIBRATE_OPTIONS``); the others are said on stderr and ignored."""
    idle = sorted(set(overrides) - CALIBRATE_OPTIONS)
    own = [f"{k} (calibrate's is {OWN_OPTIONS[k]})" for k in idle if k in OWN_OPTIONS]
    rest = [k for k in idle if k not in OWN_OPTIONS]
    if rest or own:
        what = ", ".join([*rest, *own])
        print(f"note: --set {what}: streaming option(s) that calibrate does not use (replay does): ignored",
              file=sys.stderr)
    return {k: v for k, v in overrides.items() if k in CALIBRATE_OPTIONS}


def run(args: argparse.Namespace) -> int:
    """Read the recording, fit, check against the guard rails, print, write YAML/JSON; returns the exit code."""
    sets = parse_sets(args.set)
    check_paths([("the recording", args.input)], [("-o", args.output), ("--json", args.json)])
    position = position_options(args)  # before any work, in the options' own names
    args.existing, args.node = _existing(args)
    rec = read_recording(args.input, sensor=args.sensor, topic=args.topic, order="file")
    n_read, last_stamp = len(rec.t), float(rec.t[-1]) if len(rec.t) else None
    rec, sensor, unit = prepare(_in_file_order(rec), args.sensor, args.unit, str(args.input))
    overrides = _used_options(sensor_options(sets, sensor))
    used = {k: v for k, v in overrides.items() if not (position and k == "reference_norm")}  # calibrate: --norm only
    cfg = config_for(sensor, unit, **used, **position)
    n_clean = len(rec)  # after the all-zero rows
    if cfg.drop_saturated:
        rec = drop_saturated(rec)
    if cfg.field_model() is not None:
        print(field_line(cfg, norm_given=args.norm is not None))
    points, times, dropped = _points(rec, args, cfg)
    # the white noise of the readings in time order widens the residual limit of a noisy magnetometer (as the stream's)
    noise = white_noise(np.asarray(rec.raw, dtype=np.float64)) if sensor == "mag" else 0.0
    counts = {"zero": n_read - n_clean, "saturated": n_clean - len(rec)}
    dropped = {**{k: n for k, n in counts.items() if n}, **dropped}
    extra: dict[str, Any] = {"dropped": dropped} if dropped else {}
    model = args.model or _DEFAULT_MODEL.get(args.method, "sym")
    prior_norm, fixed = _prior_norm(args, cfg)
    # an accelerometer's gravity in a known unit, as the stream fixes it (fitted, the norm took the gains' mean scale
    # and the written calibration read 1.006 g at rest); a magnetometer's the model field's, else the data's
    norm = prior_norm if cfg.sensor == "accel" or cfg.field_model() is not None else args.norm
    _check_scales(norm, args.f_scale, points)
    iters = {"max_iter": overrides["max_iter"]} if "max_iter" in overrides else {}
    try:
        cal = fit(points, model=model, method=args.method, norm=norm, loss=args.loss, f_scale=args.f_scale,
                  sensor=sensor, unit=unit, **iters)  # fmt: skip
        failure = check(cal, cfg)
        high = residual_note(cal, cfg, noise)
    except (ConvergenceError, DegenerateDataError) as exc:
        if args.no_rescue:
            raise
        cal, failure, high = None, str(exc), ""
    if (failure or high) and not args.no_rescue:
        res = rescue(times, points, failure=failure or high, model=model if model in SUPPORTED["lm"] else "sym",
                     norm=prior_norm, loss=args.loss, sensor=sensor, unit=unit, cfg=cfg, change_only=not failure,
                     noise=noise)
        if res is not None:
            return _report_rescue(res, args, cfg, n_read, extra, fixed, noise)
    if high:
        print(f"warning: {high} (no offset change located: motion or disturbances?)", file=sys.stderr)
    if cal is None:
        raise ConvergenceError(failure)
    if not (failure or high or args.no_rescue) and times is not None and args.method == "lm":
        apart = rests_apart(times, points, model=model if model in SUPPORTED["lm"] else "sym", norm=prior_norm,
                            loss=args.loss, sensor=sensor, unit=unit, cfg=cfg, noise=noise)
        if apart is not None:  # a rest in another field pulled the fit toward it (fit_rescue.rests_apart)
            cal, note = apart
            print(f"note: {note}", file=sys.stderr)
            extra["left_out"] = note
    if last_stamp is not None:
        cal = cal.replace(stamp=last_stamp)
    _print(cal, str(args.input), n_read, fixed)
    if cfg.field_model() is not None:
        extra["field_model"] = field_line(cfg, norm_given=args.norm is not None)
        note = radius_note(cal, cfg) if args.norm is None else ""
        if note:
            print(note, file=sys.stderr)
    return _guarded_write(args, cfg, {sensor: cal}, [{**result_dict(cal, str(args.input), n_read), **extra}], noise)


def _guarded_write(args: argparse.Namespace, cfg: PipelineConfig, cals: dict[str, Calibration],
                   results: list[dict[str, Any]], noise: float = 0.0, levels: dict[str, float] | None = None) -> int:
    """Write ``cals`` unless the guard rails refuse one (``EXIT_REFUSED``, nothing written); --force writes them
    marked as forced. ``levels``: a calibration's level heading figure when not the one at the configured inclination."""
    levels = levels or {}
    refused = {k: why for k, c in cals.items() if (why := refusal(c, cfg, noise, levels.get(k)))}
    if refused and not args.force:
        for k, why in refused.items():
            print(f"margcal calibrate: {k}: refused by the guard rails: {why}", file=sys.stderr)
        print("margcal calibrate: nothing written (the online calibrator would not publish this); --force writes it "
              "anyway, marked as forced", file=sys.stderr)
        return EXIT_REFUSED
    for (k, why), d in zip(((k, refused.get(k, "")) for k in cals), results, strict=True):
        if why:
            print(f"warning: {k}: written past the guard rails (--force): {why}", file=sys.stderr)
            cals[k] = forced(cals[k], why)
            d["forced"], d["method"] = why, cals[k].method
    _write(args, cals, results)
    return 0


def _write(args: argparse.Namespace, cals: dict[str, Calibration], results: list[dict[str, Any]]) -> None:
    """Write the calibrations (with the other sensors' of an existing ``-o`` file, said) and the JSON."""
    if args.output is not None:
        sensors = {s for s in (*(c.sensor for c in cals.values()), *(k.partition("_")[0] for k in cals)) if s}
        kept = {k: c for k, c in args.existing.items()
                if k.partition("_")[0].partition(":")[0] not in sensors and c.sensor not in sensors}
        if kept:
            print(f"note: {args.output} also held {', '.join(kept)}: kept, only {', '.join(sorted(sensors))} replaced",
                  file=sys.stderr)
        path = save_calibrations(args.output, {**kept, **cals}, node=args.node)
        print(f"wrote {path}")
    if args.json is not None:
        d = results[0] if len(results) == 1 else {"calibrations": results}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(d, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")


def _report_rescue(res: Rescue, args: argparse.Namespace, cfg: PipelineConfig, n_read: int, extra: dict[str, Any],
                   fixed: str, noise: float = 0.0) -> int:
    """Print the diagnosis and the calibrations it fitted, write them if the guard rails pass them; 3 when nothing
    could be fitted."""
    for line in res.lines:
        print(line)
    if res.refused:
        return 3
    cals: dict[str, Calibration] = {}
    levels: dict[str, float] = {}
    results = []
    key = cfg.sensor
    last = max((k for k, p in enumerate(res.parts) if p.calibration is not None), default=-1)
    for k, part in enumerate(res.parts):
        cal = part.calibration
        print(f"-- {part.label}: {part.n_points} samples" + (f" ({part.note})" if part.note else ""))
        if cal is None:
            continue
        _print(cal, str(args.input), n_read, fixed)
        pf = part.prior_fit
        if pf is not None:
            print(f"  updated by the data: {', '.join(pf.updated) or 'none'}")
            print(f"  from the prior:      {', '.join(pf.from_prior) or 'none'}")
        if key == "mag":
            text = figures_text(part.figures) if part.figures is not None else heading_text(cal, inclination_of(cfg))
            if text:
                print(f"  {text}")
        name = key if k == last else f"{key}_{k + 1}"  # the last calibration is the sensor's current one
        cals[name] = cal
        d = {**result_dict(cal, str(args.input), n_read), **extra}
        if part.figures is not None:  # a near-level ring held level: its figures at its own field's inclination
            f = part.figures
            levels[name] = f.level_deg
            d["near_level"] = {"heading_p95_level_deg": _finite(f.level_deg), "heading_p95_tilt30_deg": _finite(f.tilt30_deg),
                               "inclination_deg": f.inclination_deg, "note": f.vertical_note}
        d["diagnosis"] = res.kind
        d["part"] = part.label
        if pf is not None:
            d["updated"], d["from_prior"] = list(pf.updated), list(pf.from_prior)
        results.append(d)
    return _guarded_write(args, cfg, cals, results, noise, levels)


def _finite(x: float) -> float | None:
    """``x`` for JSON: None when not determined (NaN or infinite)."""
    return x if math.isfinite(x) else None
