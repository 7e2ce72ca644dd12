"""``margcal diagnose INPUT``: where the sim-to-real gap of a recording lies, which effect causes it,
how far it shrinks; ``margcal diagnose-benchmark``: the withheld-effect benchmark.

Examples::

    margcal diagnose mag.csv --sensor mag --out diag/
    margcal diagnose full_sphere.csv --sensor mag --rest-recording static_10min.csv --holdout 0.5
    margcal diagnose run.mcap --sensor accel --norm 9.80665 --out diag/
    margcal diagnose-benchmark --quick

A recording too short or static to diagnose exits 3 with the reason and no report (as ``calibrate``'s nothing to
fit); a ``--rest-recording`` must be of the same sensor in the recording's unit, with enough samples.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ..bench.diagnosis import main
from ..diagnosis import check_options, diagnose, diagnose_holdout, rest_noise, summary, validator_downstream, write_report
from ..diagnosis.progress import CommandProgress, command_steps
from ..diagnosis.twin import FIT_ERRORS
from ..diagnosis.twin_fits import MIN_SAMPLES, static_reason
from ..model.errors import ConfigError, MargCalError, one_line
from ..recordings.read import read_recording
from ..validation.shipped import load_default_validator
from . import check_paths
from .raw_units import prepare

__all__ = ["register", "run", "run_benchmark"]

RETRAIN_SETS = 400
"""Simulated sets per retrained validator."""
QUICK_RETRAIN_SETS = 100
"""Simulated sets per retrained validator with ``--quick`` (the retraining is then most of the command's time)."""


def register(subparsers: Any) -> None:
    """Add the ``diagnose`` and ``diagnose-benchmark`` subcommands."""
    p = subparsers.add_parser(
        "diagnose",
        help="sim-to-real gap of a recording: where it lies, which effect causes it, how far it shrinks",
        description="Compare a recording with its simulated twin stage by stage, fit every effect of the "
                    "simulator's registry and rank them; writes DIR/diagnosis.json and DIR/report.html.",
    )
    p.add_argument("input", type=Path, help="recording: .csv (t,x,y,z[,temp]), .mcap, .db3 or a rosbag2 directory")
    p.add_argument("--sensor", choices=("mag", "accel"), default=None, help="default: guessed from the file")
    p.add_argument("--topic", default=None, help="bag topic to read when several match")
    p.add_argument("--unit", default=None,
                   help="raw unit of the recording: T, mT, uT, nT, gauss, mG (mag), m/s^2, g, mg (accel), or counts "
                   "(any other name: not checked); refused when the readings are no Earth field or gravity in it. "
                   "Default: a bag's REP-145 unit (T, m/s^2), a CSV's inferred from the readings' size (said)")
    p.add_argument("--norm", type=float, default=None, help="reference norm of the calibrated vector (default: estimated)")
    p.add_argument("--out", type=Path, default=Path("diagnosis"), help="output directory (default ./diagnosis)")
    p.add_argument("--rest-noise", type=float, default=None,
                   help="white noise std at rest, raw units (default: estimated from the recording)")
    p.add_argument("--rest-recording", type=Path, default=None,
                   help="a static recording of the same sensor to measure the rest noise from")
    p.add_argument("--holdout", type=float, default=None, metavar="SPLIT",
                   help="also fit on the first SPLIT of the recording (in time) and report the shrink on the rest")
    p.add_argument("--n-fit", type=int, default=6000, help="samples used by the fitting stages (default 6000)")
    p.add_argument("--quick", action="store_true",
                   help="fewer fitting samples and twin seeds: about three times faster, a noisier ranking")
    p.add_argument("--shape-tolerance", type=float, default=0.0, metavar="FRACTION",
                   help="size (root sum of squares) of the cross-axis terms of W relative to its diagonal that "
                        "counts as the sensor's baseline, not as an ellipsoid_shape gap (default 0: offset and gains only)")
    p.add_argument("--no-validator", action="store_true", help="skip the validator stage and the retraining")
    p.add_argument("--no-plots", action="store_true",
                   help="report.html with its tables only: no figures, matplotlib not imported (a few seconds less)")
    p.add_argument("--retrain-sets", type=int, default=None,
                   help=f"simulated sets for the retrained validators, with and without the effect (default "
                        f"{RETRAIN_SETS}, {QUICK_RETRAIN_SETS} with --quick)")
    p.set_defaults(func=run)
    b = subparsers.add_parser("diagnose-benchmark", help="withheld-effect benchmark of the diagnosis (= margcal bench diagnosis)")
    b.add_argument("bench_args", nargs=argparse.REMAINDER, help="passed on, e.g. --quick")
    b.set_defaults(func=run_benchmark)


def _read(path: Path, sensor: str | None, topic: str | None) -> Any:
    """The recording in file order: a clock that goes back (a logger restart) is handled by the diagnosis
    (``diagnosis.core.file_order_times``), never by sorting, which would interleave the parts."""
    return read_recording(path, sensor=sensor, topic=topic, order="file")


def _rest_noise(path: Path, sensor: str, unit: str) -> float:
    """The white noise at rest of ``--rest-recording`` (``rest_noise``, raw units), checked first (ConfigError): a
    recording of the same sensor in the recording's unit (the checks of ``--unit``: an accelerometer in m/s^2 is no
    tesla magnetometer's rest), with enough samples for an estimate, whose readings vary."""
    where = f"--rest-recording {path}"
    try:
        rec = _read(path, sensor, None)
    except MargCalError as exc:
        raise ConfigError(f"{where}: {one_line(exc)}") from exc
    try:
        rest, _, _ = prepare(rec, sensor, unit, "the rest recording")
    except MargCalError as exc:
        raise ConfigError(f"{where} is no rest recording of this {sensor} in {unit or 'its unit'} (the recording's): "
                          f"{one_line(exc)}") from exc
    if len(rest) < MIN_SAMPLES:
        raise ConfigError(f"{where}: {len(rest)} sample(s); a rest noise estimate needs at least {MIN_SAMPLES}")
    noise = rest_noise(rest.raw)
    if not noise > 0.0:
        raise ConfigError(f"{where}: its readings do not vary (rest noise 0): no noise estimate; a sensor quieter than "
                          "one step of its output: give --rest-noise (about one step / sqrt(12))")
    return noise


def _undiagnosable(raw: Any) -> str:
    """Why a recording cannot be diagnosed ("" when it can): too few samples, or static (``twin_fits.static_reason``):
    it has no twin, as calibrate has nothing to fit."""
    if len(raw) < MIN_SAMPLES:
        return f"a diagnosis needs at least {MIN_SAMPLES} samples, got {len(raw)}"
    return static_reason(raw)


def run(args: argparse.Namespace) -> int:
    """Run one diagnosis and write its report; the time printed is the whole command's wall time. Exit code 3 (no
    report) for a recording that cannot be diagnosed (``_undiagnosable``)."""

    t0 = time.monotonic()
    # every option up front (exit 2, one line), not after minutes of diagnosis
    n_sets = args.retrain_sets if args.retrain_sets is not None else QUICK_RETRAIN_SETS if args.quick else RETRAIN_SETS
    check_options(norm=args.norm, rest_noise=args.rest_noise, n_fit=args.n_fit, shape_tolerance=args.shape_tolerance,
                  split=args.holdout, n_sets=n_sets, cli=True)
    check_paths([("the recording", args.input), ("the --rest-recording", args.rest_recording)], [("--out", args.out)],
                folders=("--out",))
    rec, sensor, unit = prepare(_read(args.input, args.sensor, args.topic), args.sensor, args.unit, str(args.input))
    noise = args.rest_noise
    if args.rest_recording is not None:
        noise = _rest_noise(args.rest_recording, sensor, unit)
        print(f"rest noise from {args.rest_recording}: {noise:.4g} raw units", file=sys.stderr)
    why = _undiagnosable(rec.raw)
    if why:
        print(f"margcal diagnose: cannot diagnose {args.input}: {why}; no report written", file=sys.stderr)
        return 3
    validator = None
    if not args.no_validator:

        try:
            validator = load_default_validator()
        except MargCalError as exc:
            print(f"diagnose: validator stage skipped: {exc}", file=sys.stderr)
    options = {"sensor": sensor, "norm": args.norm, "rest_noise": noise, "n_fit": args.n_fit, "validator": validator,
               "shape_tolerance": args.shape_tolerance, "quick": args.quick}
    # one bar (stderr, terminals only) across the diagnosis, the validator's retraining and the withheld part
    bar = CommandProgress(command_steps(sensor, downstream=True, holdout=args.holdout is not None), start=t0)
    try:
        diag = diagnose(rec, progress=bar, **options)
        diag.downstream = validator_downstream(diag, validator, n_sets=n_sets, progress=bar)
        extra = None
        if args.holdout is not None:
            extra = {"holdout": _holdout(rec, args.holdout, diag, options, bar)}
    finally:
        bar.close()
    jpath, hpath = write_report(diag, args.out, extra=extra, plots=not args.no_plots)
    print(summary(diag))
    if extra is not None:
        h = extra["holdout"]
        if "error" in h:
            print(f"withheld part: not measured: {h['error']}")
        else:
            print(f"withheld part: {h['effect']} fitted on the first {100 * args.holdout:.0f} % shrinks the gap of the "
                  f"rest {h['gap_before']:.2f} -> {h['gap_after']:.2f} ({100 * h['shrink']:.0f} %)")
    print(f"wrote {jpath} and {hpath} ({bar.seconds:.1f} s in all, the diagnosis {diag.seconds:.1f} s)")
    return 0


def _holdout(rec: Any, split: float, diag: Any, options: dict[str, Any], bar: CommandProgress) -> dict[str, Any]:
    """The withheld-part check of the named cause (its magnitude fitted on the first part); a part that cannot
    be diagnosed is reported, not allowed to lose the diagnosis of the whole recording (BROAD 36: the first
    half alone does not fit)."""

    best = diag.best
    if best is None or diag.cause in ("none", "unexplained"):
        return {"split": split, "named_cause": diag.cause, "error": f"the cause is {diag.cause}: no effect to test"}
    try:
        held = diagnose_holdout(rec, split=split, effect=best.name, progress=bar, **options)
    except FIT_ERRORS as exc:
        return {"split": split, "named_cause": diag.cause, "error": str(exc)}
    return {"split": split, "named_cause": diag.cause, "effect": held["effect"], "magnitude": held["magnitude"],
            "gap_before": held["gap_before"], "gap_after": held["gap_after"], "shrink": held["shrink"],
            "stages_before": held["stages_before"], "stages_after": held["stages_after"]}


def run_benchmark(args: argparse.Namespace) -> int:
    """Dispatch to ``ros_margcal.bench.diagnosis.main``."""

    return int(main(list(args.bench_args)))
