"""``margcal replay RECORDING``: the online pipeline, offline, over a rosbag2 or CSV recording.

Every Imu / MagneticField message of a bag (or every row of a CSV) goes through the same
``SensorCalibrator`` the node runs, in recording order, with the message stamps as time. The
command shows progress on stderr, prints the status timeline (every event, and the status every
``--status-every`` seconds of recording time) and the final calibration of each sensor, and can
write the timeline and final calibrations as JSON (``--json``) and a coverage plot (``--plot``: the
buffered directions as azimuth phi against elevation theta about the calibration centre, the 2D
projection of Camps et al. 2009, Fig. 5).

``--lat --lon`` give the magnetometer the World Magnetic Model's field at that position: its reference norm
and the heading figures' inclination (``position``).

``margcal replay --example`` runs the recording shipped with the package (a tumbling IMU with still
periods and a hard-iron jump half way, made by ``scripts/make_example.py``) and compares the result
with its known truth. A ``--truth`` file is read and checked before the replay: a truth in another known unit
is converted to the recording's, one in an unknown unit or of another sensor refused, a sensor it lacks said.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..model.calibration import Calibration
from ..model.calibration_file import load_calibrations
from ..model.errors import ConfigError
from ..model.geomag import decimal_year
from ..model.heading import format_bound
from ..recordings.read import read_recording
from ..recordings.recording import drop_zero_rows
from ..stream.calibrator import SensorCalibrator
from ..stream.config import PipelineConfig
from ..stream.replay import replay, replay_plan
from ..stream.status import Status
from ..stream.units import unit_scale
from ..stream.view import coverage_view
from ..validation.shipped import load_validator
from . import check_paths, plot_file
from .position import add_position_args, field_line, position_options
from .raw_units import prepare, resolve_unit
from .set_option import SET_HELP, parse_sets, sensor_options

__all__ = ["example_paths", "register", "replay", "run"]

def example_paths() -> tuple[Path, Path]:
    """The shipped example recording and its truth file."""
    data = resources.files("ros_margcal") / "data"
    return Path(str(data / "example_imu.mcap")), Path(str(data / "example_truth.yaml"))


def register(subparsers: Any) -> None:
    """Add the ``replay`` subcommand."""
    p = subparsers.add_parser("replay", help="run the streaming calibrator over a rosbag2 or CSV recording",
                              description=__doc__.splitlines()[0])
    p.add_argument("recording", nargs="?", type=Path, help="rosbag2 (.mcap/.db3 or folder) or CSV (t,x,y,z[,gx,gy,gz])")
    p.add_argument("--example", action="store_true", help="replay the example recording shipped with ros_margcal")
    p.add_argument("--sensor", choices=("mag", "accel"),
                   help="CSV: which sensor the file holds (default: from the name); bag: replay only this sensor's topics")
    p.add_argument("--topic", action="append", metavar="TOPIC",
                   help="bag: replay this Imu or MagneticField topic (repeatable; default: all; a sensor with several "
                   "topics gets one calibration per topic)")
    p.add_argument("--unit", help="raw unit of the recording: T, mT, uT, nT, gauss, mG (mag), m/s^2, g, mg (accel), or "
                   "any other name such as counts (not checked; limits learnt from the first samples); refused when the "
                   "readings are no Earth field or gravity in it. Default: a bag's REP-145 unit (T, m/s^2), a CSV's "
                   "inferred from the readings' size (said). In a bag it applies to --sensor, or to the sensor it is a "
                   "unit of (gauss: MagneticField)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help=SET_HELP)
    add_position_args(p)
    p.add_argument("--truth", type=Path, help="calibration YAML with the true calibrations, to report the error")
    p.add_argument("--status-every", type=float, default=10.0, metavar="S",
                   help="status line every S seconds of recording time (default 10; 0 = events only)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the status timeline and final calibrations as JSON")
    p.add_argument("--plot", type=plot_file, metavar="FILE.png",
                   help="write the live view (samples, covered bins, fitted ellipsoid: what RViz shows) and the coverage plot")
    p.add_argument("-q", "--quiet", action="store_true", help="no timeline, only the final calibrations")
    p.add_argument("--full-only", action="store_true",
                   help="the full path alone: no partial or early MAP calibrations (the rule before issue 14)")
    p.add_argument("--validator", type=Path, metavar="FILE.json",
                   help="a trained validator (margcal train-validator) instead of the shipped one")
    p.set_defaults(func=run)


def _truth_for(truth: dict[str, Calibration], sensor: str) -> Calibration | None:
    """The truth of ``sensor``: its own entry or the latest ``<sensor>_*`` one (largest stamp)."""
    if sensor in truth:
        return truth[sensor]
    cands = [c for k, c in truth.items() if k.startswith(f"{sensor}_")]
    return max(cands, key=lambda c: c.stamp) if cands else None


def _checked_truth(truth: dict[str, Calibration], path: Path, plan: dict[str, tuple[str, str]]) -> dict[str, Calibration]:
    """Each replayed calibrator's truth in its recording's unit, checked before the replay: a known unit converted
    (the offset and norm scale, W is a ratio of the same unit), an unknown or unconvertible one and an entry of
    another sensor refused (ConfigError); a calibrator the file has no truth for said on stderr."""
    out: dict[str, Calibration] = {}
    for name, (sensor, unit) in plan.items():
        ref = _truth_for(truth, name)
        if ref is None:
            print(f"note: the truth file {path} holds no calibration for {name} (it has {', '.join(truth) or 'none'}): "
                  "no comparison", file=sys.stderr)
            continue
        if ref.sensor and ref.sensor != sensor:
            raise ConfigError(f"the truth file {path}: its calibration for {name} is of sensor {ref.sensor!r}, "
                              f"not {sensor!r}")
        if ref.unit and unit and ref.unit != unit:
            have, want = unit_scale(sensor, ref.unit), unit_scale(sensor, unit)
            if have is None or want is None:
                raise ConfigError(f"the truth file {path}: its {name} calibration is in {ref.unit!r}, the recording in "
                                  f"{unit!r}: no known conversion between them; give a truth in {unit!r}")
            f = have / want
            print(f"truth of {name}: converted from {ref.unit} to {unit}", file=sys.stderr)
            ref = ref.replace(offset=ref.offset * f, norm=ref.norm * f, unit=unit, stats=None, covariance=None,
                              parameter_names=())
        out[name] = ref
    return out


def _compare(cal: Calibration, truth: Calibration) -> dict[str, float]:
    """Offset error over the norm, and the RMS relative norm error on 2000 uniform true directions."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    raw = truth.inverse_apply(d * truth.norm)
    e = cal.norm_error(raw) / cal.norm
    return {"offset_error_rel": float(np.linalg.norm(cal.offset - truth.offset) / truth.norm),
            "norm_error_rms_rel": float(np.sqrt(np.mean(e * e)))}


def _plot(cals: dict[str, SensorCalibrator], path: Path) -> None:
    """Per sensor the node's live view (``stream.view``, what RViz shows on /calib/markers: samples about the centre
    in field radii, covered bins, the fitted ellipsoid, coloured by state) and the buffered directions in azimuth
    and elevation (Camps et al. 2009, Fig. 5)."""
    import matplotlib  # optional dependency (plots only): imported when a plot is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"collecting": "#ffb300", "ready": "#3380ff", "calibrated": "#1acc33", "rejected": "#e61a1a"}
    n = max(1, len(cals))
    fig = plt.figure(figsize=(11, 4.5 * n))
    for row, (s, c) in enumerate(sorted(cals.items())):
        view = coverage_view(c)
        colour = colours.get(view.state, "grey")
        ax = fig.add_subplot(n, 2, 2 * row + 1, projection="3d")
        if len(view.bins):
            ax.scatter(*view.bins.T, s=8, c="0.6", marker="s", alpha=0.5, label="covered bins")
        if len(view.points):
            ax.scatter(*view.points.T, s=5, c=colour, label="buffered samples")
        if view.axes is not None and view.radii is not None:
            u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 30), np.linspace(0, np.pi, 15))
            unit = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
            surf = (unit * view.radii) @ view.axes.T
            ax.plot_wireframe(surf[..., 0], surf[..., 1], surf[..., 2], color=colour, alpha=0.3, linewidth=0.5)
        ax.set_box_aspect((1, 1, 1))
        for setlim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            setlim(-1.3, 1.3)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        ax.set_title(f"{s}: {view.state}, {100 * view.coverage:.0f} % of bins (unit: {view.radius:.4g} {view.unit})")
        ax.legend(loc="upper left", fontsize="small")
        ax2 = fig.add_subplot(n, 2, 2 * row + 2)
        q = c.up_rotation  # up_axis: the buffer holds the turned readings q v
        pts, centre = (c.buffer.points(), c.buffer.center) if q is None else (c.buffer.points() @ q, c.buffer.center @ q)
        d = pts - (c.calibration.offset if c.calibration is not None else centre)
        if c.calibration is not None:
            d = d @ c.calibration.matrix.T  # directions of the calibrated field
        theta = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))) if len(d) else np.zeros(0)
        phi = np.degrees(np.arctan2(d[:, 1], d[:, 0])) if len(d) else np.zeros(0)
        ax2.scatter(phi, theta, s=6, c=colour)
        ax2.set_xlim(-180, 180)
        ax2.set_ylim(-90, 90)
        ax2.set_xlabel("phi (azimuth), deg")
        ax2.set_ylabel("theta (elevation), deg")
        ax2.set_title(f"{s}: buffered directions, {len(d)} samples")
        ax2.grid(True, alpha=0.3)
    fig.suptitle("What the calibrators have seen (the node's /calib/markers; Camps et al. 2009, Fig. 5 projection)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _format_cal(cal: Calibration) -> str:
    m = cal.matrix
    rows = "\n".join("      [" + ", ".join(f"{x: .6f}" for x in r) + "]" for r in m)
    st = cal.stats
    fit = "" if st is None else f"    fit: {st.n_points} samples, residual RMS {100 * st.rms_relative:.3f} %\n"
    return (f"    offset: [{', '.join(f'{x:.6g}' for x in cal.offset)}] {cal.unit}\n    matrix:\n{rows}\n"
            f"    norm: {cal.norm:.6g} {cal.unit}\n{fit}    stamp: {cal.stamp:.2f} s")


def _heading_lines(st: Status) -> list[str]:
    """The predicted heading error and the partial calibration's parameters, for the final state."""
    out = []
    inc = "" if st.heading_inclination_deg is None else f", {st.heading_inclination_deg:.3g} deg field inclination"
    if st.heading_p95_level_deg is not None or st.heading_p95_tilt30_deg is not None:
        out.append(f"    heading error (predicted p95, 95 % bound{inc}): {format_bound(st.heading_p95_level_deg)} level, "
                   f"{format_bound(st.heading_p95_tilt30_deg)} at +-30 deg tilt")
    if st.heading_typical_level_deg is not None or st.heading_typical_tilt30_deg is not None:
        out.append(f"    heading error (predicted p95, typical): {format_bound(st.heading_typical_level_deg)} level, "
                   f"{format_bound(st.heading_typical_tilt30_deg)} at +-30 deg tilt")
    if st.updated_parameters:
        seen = "" if st.tilt_seen_deg is None else f" (data tilted up to {st.tilt_seen_deg:.1f} deg)"
        out.append(f"    {'partial' if st.partial else 'MAP'} calibration{seen}: updated {' '.join(st.updated_parameters)}; "
                   f"from the prior: {' '.join(st.prior_parameters) or 'none'}")
    return out


def _checked_plan(path: Path, sensor: str | None, unit: str | None,
                  topics: list[str] | None) -> tuple[str | None, str | None, dict[str, tuple[str, str]]]:
    """The sensor and unit to replay with, and name -> (sensor, raw unit) of each calibrator: a CSV's sensor and
    unit inferred when not given, a bag's units checked against its readings (``raw_units``); zero rows counted."""
    plan = replay_plan(path, sensor=sensor, unit=unit, topics=topics)
    if not plan:  # a CSV
        rec = read_recording(path, sensor=sensor, order="file")
        _, s, u = prepare(rec, sensor, unit, str(path))
        return s, u, {s: (s, u)}
    for name, (s, u, topic) in plan.items():
        rec, zeros = drop_zero_rows(read_recording(path, sensor=s, topic=topic, order="file"))
        if zeros:
            print(f"{name}: {zeros} all-zero message(s) (x = y = z = 0), dropped by the calibrator's intake", file=sys.stderr)
        given = u if unit is not None and u == unit else None
        resolve_unit(s, rec.raw, given, default=u, where=f"on {topic} of {path}")
    return sensor, unit, {name: (s, u) for name, (s, u, _) in plan.items()}


def _options(sets: dict[str, dict[str, Any]], plan: dict[str, tuple[str, str]], full_only: bool,
             position: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each replayed sensor's calibrator options from ``--set`` (those without a prefix for both, ``mag.KEY`` and
    ``accel.KEY`` for that sensor alone), ``--full-only`` and the ``position``, checked now (a ``ConfigError`` before
    the replay starts, not after)."""
    sensors = sorted({s for s, _ in plan.values()})
    unused = [s for s in ("mag", "accel") if sets.get(s) and s not in sensors]
    if unused:
        msg = f"--set {unused[0]}.KEY: the recording replays no {unused[0]} ({', '.join(sensors) or 'nothing'})"
        raise ConfigError(msg)
    extra: dict[str, Any] = {"partial_fit": False} if full_only else {}
    extra.update(position)
    year = decimal_year() if position else None  # one date for the whole replay (and for the line printed)
    out = {s: {**sensor_options(sets, s), **extra} for s in sensors}
    for opts in out.values():
        if year is not None:
            opts.setdefault("field_year", year)
    for s, u in plan.values():
        cfg = PipelineConfig.for_sensor(s, u, **out[s])
        if position and s == "mag":
            print(f"{s}: {field_line(cfg, norm_given='reference_norm' in out[s])}")
    return out


def run(args: argparse.Namespace) -> int:
    """Entry of ``margcal replay``."""
    truth_path: Path | None = args.truth
    if args.example and args.recording is not None:
        msg = f"give a RECORDING or --example, not both (--example replays the shipped recording, not {args.recording})"
        raise ConfigError(msg)
    if args.example:
        path, example_truth = example_paths()
        truth_path = truth_path or example_truth
    elif args.recording is not None:
        path = args.recording
    else:
        msg = "give a RECORDING (rosbag2 or CSV) or --example"
        raise ConfigError(msg)
    if not math.isfinite(args.status_every) or args.status_every < 0:
        msg = f"--status-every must be >= 0, got {args.status_every}"
        raise ConfigError(msg)
    check_paths([("the recording", path), ("the --truth file", truth_path), ("the --validator file", args.validator)],
                [("--json", args.json), ("--plot", args.plot)])
    position = position_options(args)  # before any work: a bad --lat/--lon/--alt/--date costs no replay
    sets = parse_sets(args.set)
    truth = load_calibrations(truth_path) if truth_path is not None else {}  # a bad file costs no replay
    sensor, unit, plan = _checked_plan(path, args.sensor, args.unit, args.topic)
    options = _options(sets, plan, args.full_only, position)
    truths = _checked_truth(truth, truth_path, plan) if truth_path is not None else {}
    validator = load_validator(args.validator) if args.validator is not None else None
    print(f"replaying {path}" + (f" with the validator {args.validator}" if validator is not None else ""))
    printer = None if args.quiet else print
    result = replay(path, sensor=sensor, unit=unit, status_every=args.status_every, on_line=printer,
                    validator=validator, topics=args.topic, sensor_options=options)
    cals: dict[str, SensorCalibrator] = result["calibrators"]
    topics: dict[str, str] = result.get("topics", {})
    summary: dict[str, Any] = {}
    print(f"\nfinal state after {result['messages']} messages:")
    for s, c in sorted(cals.items()):
        st: Status = c.status()
        entry: dict[str, Any] = {"state": st.state.value, "status": st.to_dict(),
                                 "calibration": None if c.calibration is None else c.calibration.to_dict()}
        on = f" ({topics[s]})" if topics.get(s) and ":" not in s else ""
        print(f"  {s}{on}: {st.state.value} [{st.level.name}] {st.message}")
        if topics.get(s):
            entry["topic"] = topics[s]
        if c.config.sensor == "mag" and c.config.field_model() is not None:
            entry["field_model"] = field_line(c.config, norm_given="reference_norm" in options.get("mag", {}))
            print(f"    {entry['field_model']}")
        if c.calibration is not None:
            print(_format_cal(c.calibration))
            for line in _heading_lines(st):
                print(line)
            entry["heading_p95_deg"] = {"level": st.heading_p95_level_deg, "tilt30": st.heading_p95_tilt30_deg}
            entry["heading_typical_deg"] = {"level": st.heading_typical_level_deg, "tilt30": st.heading_typical_tilt30_deg}
            entry["heading_inclination_deg"] = st.heading_inclination_deg
            entry["partial"] = {"partial": st.partial, "updated": list(st.updated_parameters),
                                "from_prior": list(st.prior_parameters), "tilt_seen_deg": st.tilt_seen_deg}
            ref = truths.get(s)
            if ref is not None:
                cmp_ = _compare(c.calibration, ref)
                entry["truth_comparison"] = cmp_
                print(f"    vs truth: offset error {100 * cmp_['offset_error_rel']:.2f} % of the norm, "
                      f"norm error {100 * cmp_['norm_error_rms_rel']:.3f} % RMS")
        summary[s] = entry
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        doc = {"recording": str(path), "messages": result["messages"], "sensors": summary, "timeline": result["timeline"]}
        args.json.write_text(json.dumps(doc, indent=1, default=_json_default), encoding="utf-8")
        print(f"wrote {args.json}")
    if args.plot is not None:
        _plot(cals, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    msg = f"not JSON serialisable: {type(x).__name__}"
    raise TypeError(msg)
