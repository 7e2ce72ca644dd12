"""The streaming calibrator against the batch fit on the real recordings of ``../shared/data/real``.

For every recording (its raw unit from the README there): replay it through ``SensorCalibrator`` (as
``margcal replay FILE --sensor S --unit U`` does) and fit the whole file as ``margcal calibrate FILE
--model sym --method lm`` does (with its diagnosis when the plain fit fails or is implausible:
static, a located offset change, the prior fit on partial coverage). The table gives the stream's
final state and why (for a recording that does not calibrate, a short true reason: one static pose, moved
throughout, a sensor change, else the final status), the time to its first calibration, and, where both calibrated, the offset
difference in % of the field and the heading p95 of the stream's calibration against the batch fit's
(level and 30° tilt, 60° inclination, 72 yaws; magnetometer only).

``--soft-iron``: instead, the shape of each full-sphere magnetometer's batch fit (``sym``, ``lm``): its
matrix over the mean of its diagonal, minus the identity: how far real sensors' gains and cross terms
are from isotropic, the scale the broad prior's matrix standard deviation
(``model.fitting_prior.BROAD_MATRIX_STD``) must cover for the terms a ground robot cannot see.

Usage::

    python scripts/study_real_recordings.py [--data DIR] [--markdown] [--soft-iron]

``--data DIR``: another folder of ``t,x,y,z`` CSVs (``*_mag.csv``, ``*_acc.csv``), its raw units in
``DIR/units.yaml`` (``units``).

A magnetometer recording with a reference attitude beside it (``NAME_attitude.csv``: ``t,yaw_deg,pitch_deg,roll_deg``
of another AHRS, e.g. a VN-100's own filter, body x forward, y right, z down) gets a second table: every calibration
the stream publishes (with the recording's rates, as ``margcal replay`` feeds them), its heading tilt-compensated with
the reference's roll and pitch, against the reference's yaw (``against_reference_yaw``: p95 of the difference after
its median, the declination and the mounting's yaw, is taken off), beside the status's level and 30° bounds; and the
same for the raw readings and the batch fit.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import yaml

from ros_margcal.cli.calibrate import still_samples
from ros_margcal.cli.calibrate_guard import refusal
from ros_margcal.cli.fit_rescue import Part, check, config_for, rescue, residual_note, rests_apart
from ros_margcal.cli.raw_units import resolve_unit
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import ConfigError, ConvergenceError, DegenerateDataError, RecordingError
from ros_margcal.model.fitting import fit
from ros_margcal.model.heading import attitudes
from ros_margcal.recordings.read import read_recording
from ros_margcal.stream.calibrator import EventKind, SensorCalibrator
from ros_margcal.stream.config import STATIC_SPREAD, relative_spread, white_noise
from ros_margcal.stream.replay import replay
from ros_margcal.stream.status import State

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"

UNITS = {  # raw unit per recording, from the README of the real recordings
    "broad_02_undisturbed_slow_rotation_B_mag.csv": "uT",
    "broad_32_disturbed_attached_magnet_1cm_mag.csv": "uT",
    "broad_36_disturbed_attached_magnet_5cm_mag.csv": "uT",
    "ck_lsm9ds1_full_sphere_mag.csv": "gauss",
    "ck_lsm9ds1_static_poses_acc.csv": "g",
    "fhoevi_full_sphere_mag.csv": "counts",
    "hamagure_lsm9ds1_full_sphere_mag.csv": "gauss",
    "hamagure_lsm9ds1_hemisphere_mag.csv": "gauss",
    "sunsided_hmc5883l_full_sphere_mag.csv": "gauss",
    "sunsided_hmc5883l_static_10min_mag.csv": "gauss",
    "sunsided_mpu6050_full_sphere_acc.csv": "g",
    "sunsided_mpu6050_unmoved-with-x-pointing-forward_acc.csv": "g",
    "sunsided_mpu6050_unmoved-with-z-pointing-front-and-x-up_acc.csv": "g",
    "sunsided_mpu6050_unmoved-with-z-pointing-front-and-y-down_acc.csv": "g",
}


def units(data: Path) -> dict[str, str]:
    """Recording -> raw unit: the shared recordings' (``UNITS``), and those another folder names in its
    ``units.yaml`` (``file.csv: uT``; e.g. a held-out set from other public repositories)."""
    extra = data / "units.yaml"
    if not extra.exists():
        return dict(UNITS)
    got = yaml.safe_load(extra.read_text()) or {}
    return {**UNITS, **{str(k): str(v) for k, v in got.items()}}


def heading_p95_against(cal: Calibration, ref: Calibration, tilt_deg: float, inclination: float = 60.0) -> float:
    """95th percentile of |heading(cal) - heading(ref)| (degrees) over yaw and tilt, on readings ``ref`` explains."""
    rot = attitudes(tilt_deg)
    inc = math.radians(inclination)
    m = ref.norm * np.array([0.0, math.cos(inc), -math.sin(inc)])
    body = np.einsum("kji,j->ki", rot, m)  # R^T m
    raw = ref.inverse_apply(body)
    h = cal.apply(raw)
    world = np.einsum("kij,kj->ki", rot, h)
    psi = np.arctan2(world[:, 0], world[:, 1])
    psi_ref = np.arctan2(np.einsum("kij,kj->ki", rot, body)[:, 0], np.einsum("kij,kj->ki", rot, body)[:, 1])
    d = np.degrees(np.angle(np.exp(1j * (psi - psi_ref))))
    return float(np.percentile(np.abs(d), 95))


def batch(path: Path, sensor: str, unit: str) -> tuple[Calibration | None, str]:
    """The batch fit as ``margcal calibrate`` makes it (the last stretch's, when the sensor changed), and a note
    (the diagnosis when it needed one)."""
    parts, note = batch_stretches(path, sensor, unit)
    return (parts[-1] if parts else None), (note.replace(" calibrations", " calibrations, last used", 1)
                                                if len(parts) > 1 else note)


def batch_stretches(path: Path, sensor: str, unit: str) -> tuple[list[Calibration], str]:
    """The batch fits as ``margcal calibrate`` makes them, in time order (one unless the offset changed in the
    recording; each stamped with the end of its stretch), and a note (the diagnosis when it needed one)."""
    parts, note = batch_parts(path, sensor, unit)
    return [p.calibration for p in parts if p.calibration is not None], note


def batch_parts(path: Path, sensor: str, unit: str) -> tuple[list[Part], str]:
    """``batch_stretches`` as ``fit_rescue.Part``s, each with its calibration: a near-level ring held level carries the
    figures ``margcal calibrate`` judges it by (``Part.figures``: its level figure at its own field's inclination)."""
    rec = read_recording(path, sensor=sensor)
    try:
        pts = still_samples(rec) if sensor == "accel" else np.asarray(rec.raw, dtype=np.float64)
    except RecordingError as exc:
        return [], f"none: {exc}"
    cfg = config_for(sensor, unit)
    noise = white_noise(np.asarray(rec.raw, dtype=np.float64)) if sensor == "mag" else 0.0  # as margcal calibrate
    try:
        cal = fit(pts, model="sym", method="lm", sensor=sensor, unit=unit)
        why, high = check(cal, cfg), residual_note(cal, cfg, noise)
    except (ConvergenceError, DegenerateDataError) as exc:
        cal, why, high = None, str(exc), ""
    if not why and not high:
        if sensor == "mag":  # a rest in another field left out, as margcal calibrate does (fit_rescue.rests_apart)
            apart = rests_apart(np.asarray(rec.t, dtype=np.float64), pts, model="sym", norm=None, loss="linear",
                                sensor=sensor, unit=unit, cfg=cfg, noise=noise)
            if apart is not None:
                return [Part("lm", apart[0], len(pts))], "lm, a rest in another field left out"
        return [Part("lm", cal, len(pts))], "lm"
    res = rescue(None if sensor == "accel" else np.asarray(rec.t, dtype=np.float64), pts, failure=why or high,
                 model="sym", norm=None, loss="linear", sensor=sensor, unit=unit, cfg=cfg, change_only=not why,
                 noise=noise)
    if res is None:
        return ([Part("lm", cal, len(pts))] if cal is not None else []), f"lm, warning: {high.split(':')[0]}"
    fitted = [p for p in res.parts if p.calibration is not None]
    if not fitted:
        return [], f"{res.kind}: refused"
    last = fitted[-1]
    note = f"{res.kind}: {len(fitted)} calibrations" if res.kind == "change" else res.kind
    if last.prior_fit is not None and last.prior_fit.from_prior:
        note += f" (from prior: {', '.join(last.prior_fit.from_prior)})"
    return fitted, note


def study(path: Path, unit: str) -> dict[str, object]:
    sensor = "accel" if path.stem.endswith("_acc") else "mag"
    try:  # the unit checked as margcal replay and calibrate check it (a gauss file read as counts is refused there)
        resolve_unit(sensor, read_recording(path, sensor=sensor, order="file").raw, unit, where=f"in {path.name}")
    except ConfigError as exc:
        return {"file": path.name, "unit": unit, "n": 0, "state": "refused (unit)", "why": str(exc), "first": None,
                "batch": "refused (unit)", "offset": None, "level": None, "tilt30": None, "changes": 0}
    out = replay(path, sensor=sensor, unit=unit, status_every=0.0, progress=False)
    cal = out["calibrators"][sensor]
    st = cal.status()
    first = next((e["t"] for e in out["timeline"] if e["kind"] == "calibrated"), None)
    ref, note = batch(path, sensor, unit)
    row: dict[str, object] = {"file": path.name, "unit": unit, "n": st.samples_seen, "state": st.state.value,
                              "why": st.message, "first": first, "batch": note, "offset": None, "level": None,
                              "tilt30": None, "changes": st.changes_detected}
    stream = cal.calibration
    if stream is not None and ref is not None:
        radius = ref.raw_radius
        row["offset"] = 100.0 * float(np.linalg.norm(stream.offset - ref.offset)) / radius
        if sensor == "mag":
            row["level"] = heading_p95_against(stream, ref, 0.0)
            row["tilt30"] = heading_p95_against(stream, ref, 30.0)
    if st.state is State.CALIBRATED and not st.message.startswith("calibrated"):
        row["why"] = st.message
    if st.state is not State.CALIBRATED:
        row["why"] = reason(path, sensor, cal, out["timeline"])
    return row


def reason(path: Path, sensor: str, cal: SensorCalibrator, timeline: list[dict[str, object]]) -> str:
    """A short true reason why the stream did not calibrate ``path``, from the data, then the final status."""
    raw = np.asarray(read_recording(path, sensor=sensor).raw, dtype=np.float64)
    spread = relative_spread(raw)
    if spread < STATIC_SPREAD:
        return (f"one static pose (the whole recording within {100 * spread:.2g} % of its mean): it fixes the norm, "
                "not the ellipsoid's 9 parameters; calibrating needs >= 9 poses")
    gate = getattr(cal, "_gate", None)
    if sensor == "accel" and cal.kept == 0 and gate is not None and not math.isfinite(gate.window_stats[0]):
        return (f"no {gate.window_s:g} s window ever filled: the poses (or stretches between stamp gaps) are shorter "
                "than the gate's window; no still pose for an accelerometer fit")
    if sensor == "accel" and cal.kept == 0 and gate is not None:
        return (f"moved all through the recording: no {gate.window_s:g} s window still (last window CV "
                f"{gate.window_stats[0]:.3g}, axis spread {gate.window_stats[1]:.3g}; the learnt gate's cap is "
                f"{gate.plain.learn_cap:.3g}): no still pose for an accelerometer fit")
    changed = [e for e in timeline if e.get("kind") == "changed"]
    if changed:
        magnet = " (the magnet put on or taken off)" if "magnet" in path.name else ""
        return (f"a sensor change at t={float(changed[-1]['t']):.0f} s{magnet}, too little turning "
                f"after it to calibrate the changed sensor; final status: {cal.status().message}")
    return f"final status: {cal.status().message}"


def reference_heading_p95(h: np.ndarray, att: np.ndarray) -> float:
    """p95 (deg) of the heading of the field ``h`` (N, 3), tilt-compensated with the reference's roll and pitch
    (``att``: N rows of yaw, pitch, roll in degrees; NED body axes), against the reference's yaw, its median taken off;
    the heading's sense taken from the data (a reference of another handedness turns the other way)."""
    yaw, pitch, roll = np.radians(att[:, 0]), np.radians(att[:, 1]), np.radians(att[:, 2])
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    hx = h[:, 0] * cp + h[:, 1] * sr * sp + h[:, 2] * cr * sp
    hy = h[:, 1] * cr - h[:, 2] * sr
    psi, ref = np.unwrap(np.arctan2(-hy, hx)), np.unwrap(yaw)
    if len(psi) > 2 and np.dot(np.diff(psi), np.diff(ref)) < 0:
        psi = -psi
    d = np.degrees(psi - ref)
    d = (d - np.median(d) + 180.0) % 360.0 - 180.0
    return float(np.percentile(np.abs(d), 95))


def against_reference_yaw(path: Path, unit: str) -> list[str]:
    """Lines of the reference-yaw table for a magnetometer recording with ``NAME_attitude.csv`` beside it ([] without)."""
    ref_path = path.with_name(path.name.replace("_mag.csv", "_attitude.csv"))
    if not path.name.endswith("_mag.csv") or not ref_path.exists():
        return []
    a = np.genfromtxt(ref_path, delimiter=",", names=True)
    rec = read_recording(path, sensor="mag")
    t, raw = np.asarray(rec.t, dtype=np.float64), np.asarray(rec.raw, dtype=np.float64)
    att = np.column_stack([np.interp(t, a["t"], np.degrees(np.unwrap(np.radians(a[k]))))
                           for k in ("yaw_deg", "pitch_deg", "roll_deg")])
    name = path.name
    lines = [f"| {name} | uncalibrated | — | {reference_heading_p95(raw, att):.2f}° | — | — |"]
    cal = SensorCalibrator("mag", config_for("mag", unit))
    gyro = None if rec.gyro is None else np.asarray(rec.gyro, dtype=np.float64)
    for k, tk in enumerate(t.tolist()):
        for e in cal.push(tk, raw[k], None if gyro is None else gyro[k]):
            if e.calibration is None or e.kind is not EventKind.CALIBRATED:
                continue
            st = cal.status(tk)
            lines.append(f"| {name} | stream | {tk - t[0]:.1f} s | {reference_heading_p95(e.calibration.apply(raw), att):.2f}° "
                         f"| {_f(st.heading_p95_level_deg, '{:.2f}°')} | {_f(st.heading_p95_tilt30_deg, '{:.2f}°')} |")
    ref, note = batch(path, "mag", unit)
    if ref is not None:
        why = refusal(ref, config_for("mag", unit), white_noise(raw))
        note += "; margcal calibrate refuses it: " + why.split(":")[0] if why else ""
        lines.append(f"| {name} | batch fit ({note}) | — | {reference_heading_p95(ref.apply(raw), att):.2f}° | — | — |")
    return lines


def soft_iron_survey(data: Path) -> None:
    """Print each full-sphere magnetometer's matrix deviation from isotropic (module docstring)."""
    print(f"{'recording':42s} {'w_xx':>6s} {'w_yy':>6s} {'w_zz':>6s} {'w_xy':>6s} {'w_xz':>6s} {'w_yz':>6s}  "
          f"{'z gain vs x, y':>14s}")
    for name in sorted(units(data)):
        if not (name.endswith("_mag.csv") and ("full_sphere" in name or "undisturbed" in name)) or not (data / name).exists():
            continue
        rec = read_recording(data / name, sensor="mag")
        w = fit(rec.raw, model="sym", method="lm").matrix
        dev = w / np.mean(np.diag(w)) - np.eye(3)
        z_vs_h = w[2, 2] / (0.5 * (w[0, 0] + w[1, 1])) - 1.0
        print(f"{name:42s} " + " ".join(f"{100 * v:+5.1f}%" for v in (*np.diag(dev), dev[0, 1], dev[0, 2], dev[1, 2]))
              + f"  {100 * z_vs_h:+13.1f}%")


def _f(x: object, fmt: str) -> str:
    return "—" if x is None else fmt.format(x)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--markdown", action="store_true", help="print a README table")
    ap.add_argument("--soft-iron", action="store_true", help="the full-sphere magnetometers' matrix shapes instead")
    args = ap.parse_args(argv)
    if not args.data.is_dir():
        print(f"no real recordings at {args.data}", file=sys.stderr)
        return 1
    if args.soft_iron:
        soft_iron_survey(args.data)
        return 0
    known = units(args.data)
    rows = [study(args.data / name, known[name]) for name in sorted(known)
            if (args.data / name).exists() and name.endswith(("_mag.csv", "_acc.csv"))]  # (a folder's other files: no sensor)
    print("| recording | unit | stream | first calibration | why (final status) | batch fit | offset diff | "
          "heading p95 level / 30° |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        why = str(r["why"]).replace("|", "/")
        if len(why) > 220:
            why = why[:217] + "..."
        print(f"| {r['file']} | {r['unit']} | {r['state']}{' (' + str(r['changes']) + ' change)' if r['changes'] else ''}"
              f" | {_f(r['first'], '{:.0f} s')} | {why} | {r['batch']} | {_f(r['offset'], '{:.2f} %')} | "
              f"{_f(r['level'], '{:.2f}°')} / {_f(r['tilt30'], '{:.2f}°')} |")
    yaw_rows = [line for name in sorted(known) if (args.data / name).exists()
                for line in against_reference_yaw(args.data / name, known[name])]
    if yaw_rows:
        print("\n| recording | calibration | published at | heading p95 vs the reference yaw | level bound | 30° bound |")
        print("| --- | --- | --- | --- | --- | --- |")
        print("\n".join(yaw_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
