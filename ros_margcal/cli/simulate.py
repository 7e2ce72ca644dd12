"""``margcal simulate``: write a simulated recording (CSV or rosbag2) and optionally its true calibration.

Examples::

    margcal simulate out.csv --sensor mag --pattern cap --param half_angle_deg=60 -n 300 --noise 0.01
    margcal simulate out.mcap --sensor imu --pattern tumbling --duration 120 --effect bias_drift=0.02
    margcal simulate out.csv --sensor accel --pattern tumbling --rate 100 --truth truth.yaml
    margcal simulate out.mcap --sensor imu --pattern tumbling --duration 300 --jump-at 150 --truth t.yaml
"""

from __future__ import annotations

import argparse
import ast
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..model.calibration_file import save_calibrations
from ..model.errors import ConfigError
from ..recordings.bag import BAG_SUFFIXES, write_bag
from ..recordings.csvfile import write_csv
from ..recordings.recording import Recording
from ..sim.simulation import (
    EFFECTS,
    PATTERNS,
    HardIronJump,
    directions,
    magnetometer_stream,
    random_sensor,
    simulate,
    tumbling,
    tumbling_motion,
)
from . import check_paths

__all__ = ["register", "run"]

TIME_SERIES = ("tumbling", "smooth")
TOPICS = {"accel": "/imu/data_raw", "mag": "/imu/mag"}


def _key_value(text: str) -> tuple[str, str]:
    if "=" not in text:
        msg = f"expected name=value, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    key, value = text.split("=", 1)
    return key.strip(), value.strip()


def _effect(text: str) -> tuple[str, float]:
    name, value = _key_value(text)
    if name not in EFFECTS:
        msg = f"unknown effect {name!r}; choose from {', '.join(sorted(EFFECTS))}"
        raise argparse.ArgumentTypeError(msg)
    try:
        return name, float(value) if value else EFFECTS[name].default_magnitude
    except ValueError:
        msg = f"effect magnitude must be a number, got {value!r}"
        raise argparse.ArgumentTypeError(msg) from None


def _param(text: str) -> tuple[str, Any]:
    key, value = _key_value(text)
    try:
        return key, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return key, value


def register(subparsers: Any) -> None:
    """Add the ``simulate`` subcommand."""
    effects_help = "; ".join(f"{n} [{e.magnitude_unit}, e.g. {e.default_magnitude:g}]" for n, e in EFFECTS.items())
    p = subparsers.add_parser(
        "simulate",
        help="write a simulated recording (CSV or rosbag2 .mcap/.db3) from a random true sensor",
        description="Simulate raw sensor data from a random true calibration. Output format by suffix: "
        ".csv, .mcap, .db3, or a directory (rosbag2). Effects: " + effects_help,
    )
    p.add_argument("output", type=Path, help="output file (.csv, .mcap, .db3) or rosbag2 directory")
    p.add_argument("--sensor", choices=("mag", "accel", "imu"), default="mag",
                   help="sensor to simulate; imu = accelerometer+gyro and magnetometer on one motion (bags only)")
    p.add_argument("--pattern", choices=(*PATTERNS, *TIME_SERIES), default="uniform",
                   help="coverage pattern of n samples, or a time series: tumbling (still periods), smooth (mag)")
    p.add_argument("--param", type=_param, action="append", default=[], metavar="KEY=VALUE",
                   help="pattern parameter, e.g. half_angle_deg=60 or axis=(1,0,0) (repeatable)")
    p.add_argument("-n", "--n", type=int, default=300, help="number of samples of a pattern (default 300)")
    p.add_argument("--duration", type=float, default=60.0, help="length of a time series, s (default 60)")
    p.add_argument("--rate", type=float, default=None,
                   help="sample rate, Hz (default 100 for accel/imu time series, 50 for mag, 1 for patterns)")
    p.add_argument("--noise", type=float, default=None, help="white noise std as a fraction of the norm "
                   "(default 0.005; 0.002 for tumbling accelerometers)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--model", choices=("eye", "diag", "sym"), default="sym", help="true sensor model (default sym)")
    p.add_argument("--effect", type=_effect, action="append", default=[], metavar="NAME=MAGNITUDE",
                   help="add an effect (repeatable); an empty magnitude uses the default")
    p.add_argument("--jump-at", type=float, default=None, metavar="SECONDS",
                   help="magnetometer time series: a hard-iron jump at this time (truth file gets mag_before/mag_after)")
    p.add_argument("--jump-size", type=float, default=0.8, metavar="FRACTION",
                   help="size of the hard-iron jump as a fraction of the field norm, random direction (default 0.8)")
    p.add_argument("--truth", type=Path, default=None, help="also write the true calibration(s) as YAML")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage of a bag directory")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=run)


def _make(args: argparse.Namespace, rng: np.random.Generator) -> dict[str, Recording]:
    effects = dict(args.effect)
    params = dict(args.param)
    kinds = ("accel", "mag") if args.sensor == "imu" else (args.sensor,)
    truths = {k: random_sensor(rng, k, model=args.model) for k in kinds}
    out: dict[str, Recording] = {}
    if args.pattern in PATTERNS:
        if args.jump_at is not None:
            msg = "--jump-at needs a time series (--pattern tumbling or smooth)"
            raise ConfigError(msg)
        if args.sensor == "imu":
            msg = "--sensor imu needs a time series (--pattern tumbling)"
            raise ConfigError(msg)
        rate = args.rate or 1.0
        t = np.arange(args.n) / rate
        truth = truths[args.sensor]
        dirs = directions(args.pattern, args.n, rng, **params)
        noise = 0.005 if args.noise is None else args.noise
        out[args.sensor] = simulate(truth, dirs, noise=noise, rng=rng, t=t, effects=effects)
        return out
    if params:
        msg = f"--param applies to coverage patterns, not to the {args.pattern!r} time series"
        raise ConfigError(msg)
    events = []
    if args.jump_at is not None:
        if "mag" not in kinds:
            msg = "--jump-at is a magnetometer event; use --sensor mag or imu"
            raise ConfigError(msg)
        direction = rng.normal(size=3)
        delta = args.jump_size * truths["mag"].norm * direction / np.linalg.norm(direction)
        events.append(HardIronJump(args.jump_at, (float(delta[0]), float(delta[1]), float(delta[2]))))
    if args.pattern == "smooth" and args.sensor != "mag":
        msg = "--pattern smooth is a magnetometer motion; use tumbling for accel/imu"
        raise ConfigError(msg)
    rate = args.rate or (50.0 if args.sensor == "mag" else 100.0)
    motion = tumbling_motion(args.duration, rate, rng) if args.pattern == "tumbling" else "smooth"
    for k in kinds:
        eff = {n: m for n, m in effects.items() if k in EFFECTS[n].sensors or args.sensor != "imu"}
        if k == "accel":
            noise = 0.002 if args.noise is None else args.noise
            out[k] = tumbling(truths[k], args.duration, rate, rng, noise=noise, effects=eff,
                              motion=motion if not isinstance(motion, str) else None)
        else:
            noise = 0.005 if args.noise is None else args.noise
            mag_rate = rate / 2 if args.sensor == "imu" else rate
            out[k] = magnetometer_stream(truths[k], args.duration, mag_rate, rng, motion=motion, noise=noise, effects=eff,
                                         events=events)
    return out


MAX_SAMPLES = 10_000_000
"""The most samples ``simulate`` writes per sensor (--n, or --duration x --rate): 240 MB of readings."""

EFFECT_LIMITS = {"noise": 1.0, "quantization": 1.0, "misalignment": 180.0, "bias_drift": 1.0, "temperature": 1.0,
                 "disturbance": 10.0, "hard_iron_jump": 10.0}
"""The largest magnitude ``--effect`` takes for the effects the registry leaves unbounded (``Effect.limit`` inf), in
their units: noise and an LSB step below the field (as ``--noise``), a turn of at most 180 deg, a drift of a field
per minute or per K, a burst or step of ten fields (as ``--jump-size``). Beyond them the readings are NaN, zero or
1e296: no sensor's."""


def _check_sizes(args: argparse.Namespace) -> None:
    """Refuse absurd sizes, rates, noise and seeds at once, in the options' own words (not a numpy error, an
    allocation of terabytes or a loop that never ends deep inside the simulator)."""
    if args.seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {args.seed}")
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(f"--duration must be a positive number of seconds, got {args.duration}")
    if args.rate is not None and not (math.isfinite(args.rate) and 1e-3 <= args.rate <= 1e6):
        raise ConfigError(f"--rate must be in [0.001, 1e6] Hz, got {args.rate}")
    if args.noise is not None and not (math.isfinite(args.noise) and 0.0 <= args.noise < 1.0):
        raise ConfigError(f"--noise must be a fraction of the norm in [0, 1), got {args.noise}")
    if not (math.isfinite(args.jump_size) and 0.0 <= args.jump_size <= 10.0):
        raise ConfigError(f"--jump-size must be a fraction of the field norm in [0, 10], got {args.jump_size}")
    if args.jump_at is not None and not math.isfinite(args.jump_at):
        raise ConfigError(f"--jump-at must be a finite time in seconds, got {args.jump_at}")
    for name, m in args.effect:  # the registry's own limits (Effect.limit) are checked by the simulator
        top = EFFECT_LIMITS.get(name, math.inf)
        if not (math.isfinite(m) and 0.0 <= m <= top):
            within = f"in [0, {top:g}] ({EFFECTS[name].magnitude_unit})" if math.isfinite(top) else ">= 0"
            raise ConfigError(f"effect {name} magnitude must be {within}, got {m:g}")
    if args.pattern in PATTERNS:
        if args.n > MAX_SAMPLES:
            raise ConfigError(f"-n must be at most {MAX_SAMPLES:.0e} samples, got {args.n}")
        return
    rate = args.rate or (50.0 if args.sensor == "mag" else 100.0)
    n = args.duration * rate
    if not 2.0 <= n <= MAX_SAMPLES:
        raise ConfigError(f"--duration x --rate gives {n:.3g} samples; a time series needs 2 to {MAX_SAMPLES:.0e}")
    mag_rate = rate / 2 if args.sensor == "imu" else rate  # the magnetometer's samples (motion.sample_times)
    last = (max(2, round(args.duration * mag_rate)) - 1) / mag_rate
    if args.jump_at is not None and args.sensor != "accel" and not 0.0 < args.jump_at < last:  # accel: refused in _make
        raise ConfigError(f"--jump-at must be a time within the recording (after 0 and before {last:g} s), got "
                          f"{args.jump_at:g}: the jump would not happen, yet the truth file would say mag_before/mag_after")


def run(args: argparse.Namespace) -> int:
    """Simulate and write; returns the exit code."""
    _check_sizes(args)
    out: Path = args.output
    is_csv = out.suffix.lower() == ".csv"
    bag_dir = not is_csv and out.suffix not in BAG_SUFFIXES
    check_paths([], [("the output", out), ("--truth", args.truth)], folders=("the output",) if bag_dir else ())
    if args.truth is not None and args.truth.exists() and not args.force:
        msg = f"--truth {args.truth} exists already; pass --force to replace it"
        raise ConfigError(msg)
    if is_csv and args.sensor == "imu":
        msg = "a CSV holds one sensor; use --sensor mag or accel, or write a bag (.mcap/.db3)"
        raise ConfigError(msg)
    if is_csv and out.exists() and not args.force:
        msg = f"{out} exists already; pass --force to replace it"
        raise ConfigError(msg)
    recs = _make(args, np.random.default_rng(args.seed))
    if is_csv:
        write_csv(out, next(iter(recs.values())))
    else:
        storage = args.storage if out.suffix not in BAG_SUFFIXES else ("mcap" if out.suffix == ".mcap" else "sqlite3")
        write_bag(out, {TOPICS[k]: r for k, r in recs.items()}, storage=storage, overwrite=args.force)
    for kind, rec in recs.items():
        effects = ", ".join(f"{n}={m:g}" for n, m in rec.effects.items()) or "none"
        print(f"{kind}: {len(rec)} samples over {rec.t[-1] - rec.t[0]:.1f} s, effects: {effects}")
    print(f"wrote {out}")
    if args.truth is not None:
        truths = {k: r.truth for k, r in recs.items() if r.truth is not None}
        mag = recs.get("mag")
        if args.jump_at is not None and mag is not None:
            truths["mag_before"] = truths.pop("mag")
            truths["mag_after"] = mag.truth_at(mag.t[-1]).replace(stamp=float(args.jump_at))
        save_calibrations(args.truth, truths)
        print(f"wrote true calibration(s) {', '.join(truths)} to {args.truth}")
    return 0
