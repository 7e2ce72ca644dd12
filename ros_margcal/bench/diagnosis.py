"""Withheld-effect benchmark of the sim-to-real diagnosis (``margcal bench diagnosis [--quick]``).

1. Blind attribution: for every effect of the registry and sensor, at several magnitudes (multiples of
   the effect's default) and two coverages, a recording is simulated with that effect on a baseline
   sensor (offset + gains, white noise) and diagnosed without being told the effect. The truth label is
   the effect's equivalence group when the group has several members for that sensor
   (``ellipsoid_shape``; ``slow_drift`` for bias drift and temperature when the recording has no
   temperature column — the simulator writes one only with the temperature effect, so this is the
   bias-drift recordings), and ``none`` for unobservable effects (misalignment). A strict figure
   (top-ranked effect = the withheld one, drift group not merged) is printed too. Prints the confusion
   matrix (also ``confusion.png``), top-1 accuracy, the median shrink of the effect recordings and the
   ``none`` rate on baseline-only recordings. Accelerometer recordings are tumbling series cut to
   their still samples (what the inactivity gate passes on; ``motion_leak`` adds acceleration there).
   Targets: top-1 >= 90 %, median shrink >= 80 %, none >= 90 %. The diagnosis is given the rest
   noise of the sensor (as from a static recording); otherwise the ``noise`` effect would be
   indistinguishable from the baseline's own noise.
2. Real recordings (``--real-dir``, default ``../shared/data/real`` beside the checkout, skipped when
   absent): the effect is fitted on the first half and the gap measured on the withheld second half
   (``holdout.png``).
3. Speed: one diagnosis of a 5-minute 100 Hz recording (30000 samples), validator stage included.

``--effects a,b`` / ``--sensor`` / ``--limit N`` run a subset of part 1 (e.g. the misses of a previous
run; the targets apply to the full run), ``--no-real`` / ``--no-speed`` skip parts 2 and 3, ``--seed K``
draws other recordings of the same design. Each finished recording is appended to ``rows.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..diagnosis import diagnose, diagnose_holdout
from ..diagnosis.ranking import effective_group
from ..diagnosis.report import _plt, figure_png
from ..model.errors import MargCalError
from ..recordings.read import read_recording
from ..sim.simulation import EFFECTS, magnetometer_stream, random_sensor, tumbling
from ..validation.shipped import load_default_validator

__all__ = ["main", "speed_recording"]

_REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"  # ../shared beside the checkout
_REAL_FILES = ("sunsided_hmc5883l_full_sphere_mag.csv", "ck_lsm9ds1_full_sphere_mag.csv", "hamagure_lsm9ds1_full_sphere_mag.csv",
               "broad_02_undisturbed_slow_rotation_B_mag.csv", "broad_32_disturbed_attached_magnet_1cm_mag.csv",
               "sunsided_mpu6050_full_sphere_acc.csv", "ck_lsm9ds1_static_poses_acc.csv")
_NOISE = {"mag": 0.005, "accel": 0.002}


def _make(sensor: str, effect: str | None, magnitude: float, coverage: str, seed: int, duration: float) -> tuple[Any, float]:

    rng = np.random.default_rng([seed, 7])
    truth = random_sensor(rng, sensor, model="diag")
    eff = None if effect is None else {effect: magnitude}
    noise = _NOISE[sensor]
    if sensor == "mag":
        rec = magnetometer_stream(truth, duration, 50.0, rng, motion=coverage, noise=noise, effects=eff)
    else:
        rec = tumbling(truth, duration, 50.0, rng, still_fraction=0.6 if coverage == "slow" else 0.3, noise=noise,
                       effects=eff)
        rec = rec.slice(rec.still)  # what the inactivity gate passes on: the still samples (motion_leak leaks in)
    return rec, noise * truth.raw_radius


def _exit_with_parent(parent: int) -> None:
    """A pool worker's initializer: exit when the benchmark's process is gone (killed by a timeout or SIGKILL, it
    cannot end its pool, and the workers would run on as orphans)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)
    threading.Thread(target=watch, daemon=True).start()


def _case(job: tuple[str, str | None, float, str, int, float]) -> dict[str, Any]:

    sensor, effect, magnitude, coverage, seed, duration = job
    rec, rest = _make(sensor, effect, magnitude, coverage, seed, duration)
    t0 = time.monotonic()
    has_temp = rec.temp is not None and bool(np.ptp(rec.temp) > 0)
    base = {"sensor": sensor, "effect": effect or "none", "magnitude": magnitude, "coverage": coverage, "seed": seed,
            "has_temp": has_temp}
    try:
        d = diagnose(rec, sensor=sensor, rest_noise=rest)
    except Exception as exc:  # counted as a miss and as a traceback (a diagnosis must always give a verdict)
        kind = "error" if isinstance(exc, MargCalError) else "traceback"
        return {**base, "cause": kind, "best": "", "shrink": 0.0, "gap_before": 0.0, "gap_after": 0.0,
                "where": f"{type(exc).__name__}: {exc}"[:80], "fitted": 0.0, "seconds": time.monotonic() - t0}
    return {**base, "cause": d.cause, "best": d.best.name if d.best else "", "shrink": d.shrink,
            "gap_before": d.gap_before, "gap_after": d.gap_after, "where": d.where,
            "fitted": d.best.magnitude if d.best else 0.0, "seconds": time.monotonic() - t0,
            "ranking": [[f.name, f.shrink, f.magnitude] for f in d.effects[:3]]}


def _label(sensor: str, effect: str, has_temp: bool = True) -> str:
    """The cause a correct diagnosis names: the effect, or its group when the data cannot tell the
    group's members apart (``diagnosis.effects.effective_group``), ``none`` for unobservable effects."""

    if effect == "none" or not EFFECTS[effect].observable:
        return "none"
    e = EFFECTS[effect]
    group = effective_group(e, has_temp)
    members = [x for x in EFFECTS.values() if x.observable and sensor in x.sensors and effective_group(x, has_temp) == group]
    return group if len(members) > 1 else e.name


def _strict_hit(row: dict[str, Any]) -> bool:
    """The top-ranked effect is the withheld one (or in its registry group), groups of the data not merged."""

    label = _label(row["sensor"], row["effect"], True)
    if label == "none" or row["cause"] in ("none", "unexplained", "error"):
        return label == row["cause"]
    return bool(row["best"]) and EFFECTS[row["best"]].group == EFFECTS[row["effect"]].group


def _jobs(quick: bool, seed: int = 0) -> list[tuple[str, str | None, float, str, int, float]]:
    """The benchmark's recordings; ``seed`` shifts every recording's seed (another draw of the same design)."""

    factors = (2.0,) if quick else (1.0, 2.0, 4.0)
    covers = {"mag": ("smooth",) if quick else ("smooth", "tumble"), "accel": ("slow",) if quick else ("slow", "busy")}
    n_none = 3 if quick else 10
    duration = 60.0 if quick else 120.0
    jobs: list[tuple[str, str | None, float, str, int, float]] = []
    for sensor in ("mag", "accel"):
        for cov in covers[sensor]:
            for i, e in enumerate(x for x in EFFECTS.values() if sensor in x.sensors):
                for j, f in enumerate(factors):
                    m = min(f * e.default_magnitude, e.magnitude_range[1])
                    jobs.append((sensor, e.name, m, cov, 100 * i + j + seed, duration))
            jobs += [(sensor, None, 0.0, cov, 1000 + k + seed, duration) for k in range(n_none)]
    return jobs


def _select(jobs: list[tuple[str, str | None, float, str, int, float]], effects: str, sensor: str, limit: int,
            ) -> list[tuple[str, str | None, float, str, int, float]]:
    """The jobs of the named effects (comma-separated, ``none`` for the baseline-only recordings; empty: all)
    and sensor (empty: both), at most ``limit`` of them (0: all), spread evenly over the selection."""

    names = [x.strip() for x in effects.split(",") if x.strip()]
    unknown = sorted(set(names) - set(EFFECTS) - {"none"})
    if unknown:
        msg = f"unknown effect(s) {unknown}; choose from {sorted(EFFECTS)} or none"
        raise SystemExit(msg)
    out = [j for j in jobs if (not names or (j[1] or "none") in names) and (not sensor or j[0] == sensor)]
    if 0 < limit < len(out):
        out = [out[int(k)] for k in np.linspace(0, len(out) - 1, limit).round()]
    return out


def _confusion(rows: list[dict[str, Any]], out: Path) -> tuple[str, Path]:
    truth = [_label(r["sensor"], r["effect"], r["has_temp"]) for r in rows]
    return _confusion_plot(truth, [r["cause"] for r in rows], out, "confusion.png",
                           "withheld effect (group; unobservable -> none)")


def _confusion_plot(truth: list[str], pred: list[str], out: Path, name: str, ylabel: str) -> tuple[str, Path]:
    """The confusion matrix of ``truth`` against ``pred`` as text and as ``out/name`` (PNG)."""
    labels = sorted(set(truth) | set(pred))
    mat = np.zeros((len(labels), len(labels)), dtype=int)
    for a, b in zip(truth, pred, strict=True):
        mat[labels.index(a), labels.index(b)] += 1
    w = max(len(s) for s in labels)
    lines = [" " * (w + 2) + " ".join(f"{s[:6]:>6s}" for s in labels)]
    lines += [f"{a:>{w}s}  " + " ".join(f"{v:6d}" for v in mat[i]) for i, a in enumerate(labels)]

    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 7))
    ax.imshow(mat, cmap="Blues")
    ax.set_xticks(range(len(labels)), labels, rotation=60, fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    for i in range(len(labels)):
        for j in range(len(labels)):
            if mat[i, j]:
                ax.text(j, i, str(mat[i, j]), ha="center", va="center", fontsize=8)
    ax.set_xlabel("diagnosed cause")
    ax.set_ylabel(ylabel)
    png = out / name
    png.write_bytes(figure_png(fig))
    return "\n".join(lines), png


def _real(real_dir: Path, out: Path, quick: bool) -> list[dict[str, Any]]:

    files = [real_dir / f for f in _REAL_FILES if (real_dir / f).is_file()][: 2 if quick else None]
    rows = []
    for f in files:
        rec = read_recording(f)
        sensor = "accel" if "_acc" in f.name else "mag"
        t0 = time.monotonic()
        try:
            h = diagnose_holdout(rec, split=0.5, sensor=sensor, n_fit=4000)
        except Exception as exc:  # report and go on: one odd file must not stop the benchmark
            print(f"  {f.name}: {exc}")
            continue
        rows.append({"file": f.name, "cause_first_half": h["fit"].cause, "effect": h["effect"], "magnitude": h["magnitude"],
                     "shrink_first_half": h["fit"].shrink, "gap_before_withheld": h["gap_before"],
                     "gap_after_withheld": h["gap_after"], "shrink_withheld": h["shrink"],
                     "seconds": time.monotonic() - t0})
        r = rows[-1]
        print(f"  {f.name:50s} first half: {r['cause_first_half']:16s} ({r['effect']} {r['magnitude']:.3g}, "
              f"shrink {100 * r['shrink_first_half']:.0f} %)  withheld half: gap {r['gap_before_withheld']:.1f} -> "
              f"{r['gap_after_withheld']:.1f} ({100 * r['shrink_withheld']:.0f} %), {r['seconds']:.0f} s", flush=True)
    if rows:
        plt = _plt()
        fig, ax = plt.subplots(figsize=(10, 3.5))
        x = np.arange(len(rows))
        ax.bar(x - 0.2, [r["gap_before_withheld"] for r in rows], 0.4, label="baseline twin")
        ax.bar(x + 0.2, [r["gap_after_withheld"] for r in rows], 0.4, label="twin + effect fitted on the first half")
        ax.set_xticks(x, [f"{r['file'][:28]}\n({r['effect']})" for r in rows], fontsize=7, rotation=15)
        ax.set_yscale("log")
        ax.set_ylabel("overall gap on the withheld half")
        ax.legend(fontsize=8)
        (out / "holdout.png").write_bytes(figure_png(fig))
    return rows


def speed_recording() -> Any:
    """The speed case: a simulated 5-minute, 100 Hz magnetometer recording (30000 samples) with soft iron."""
    rng = np.random.default_rng(5)
    truth = random_sensor(rng, "mag", model="diag")
    return magnetometer_stream(truth, 300.0, 100.0, rng, noise=0.005, effects={"soft_iron": 0.05})


def _speed() -> float:

    rec = speed_recording()
    t0 = time.monotonic()
    diagnose(rec, sensor="mag", validator=load_default_validator())
    return time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns 0 when all three targets are met, 1 otherwise."""
    p = argparse.ArgumentParser(prog="margcal bench diagnosis", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="one magnitude, one coverage, 60 s recordings")
    p.add_argument("--out", type=Path, default=Path("bench_out/diagnosis"), help="directory for the PNGs and JSON")
    p.add_argument("--real-dir", type=Path, default=_REAL, help="real recordings (skipped when absent)")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="worker processes")
    p.add_argument("--seed", type=int, default=0, help="added to every recording's seed (another draw of the design)")
    p.add_argument("--effects", default="", help="only these withheld effects, comma-separated ('none': baseline-only)")
    p.add_argument("--sensor", choices=("mag", "accel"), default="", help="only this sensor")
    p.add_argument("--limit", type=int, default=0, help="at most this many recordings (spread over the selection)")
    p.add_argument("--no-real", action="store_true", help="skip the real recordings")
    p.add_argument("--no-speed", action="store_true", help="skip the 5-minute speed run")
    args = p.parse_args(argv)
    if args.limit < 0 or args.jobs < 1:
        p.error(f"--limit must be >= 0 (0: every recording) and --jobs >= 1, got {args.limit} and {args.jobs}")
    if args.seed < 0:  # one line, as the CLI's (not numpy's traceback in a worker)
        p.exit(2, f"{p.prog}: error: --seed must be a non-negative integer, got {args.seed}\n")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rows.jsonl").unlink(missing_ok=True)
    design = _jobs(args.quick, args.seed)
    jobs = _select(design, args.effects, args.sensor, args.limit)
    subset = len(jobs) < len(design)
    t0 = time.monotonic()
    rows: list[dict[str, Any]] = []
    with multiprocessing.get_context("fork").Pool(args.jobs, _exit_with_parent, (os.getpid(),)) as pool:
        for r in pool.imap_unordered(_case, jobs):
            rows.append(r)
            with (args.out / "rows.jsonl").open("a") as fh:  # follow a long run as it goes
                fh.write(json.dumps(r) + "\n")
            print(f"\rdiagnosis bench: {len(rows)}/{len(jobs)} recordings, {time.monotonic() - t0:.0f} s",
                  end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    rows.sort(key=lambda r: (r["sensor"], r["effect"], r["coverage"], r["magnitude"]))
    print("withheld effect        sensor cover   magnitude  seed -> diagnosed          shrink  where")
    for r in rows:
        print(f"{r['effect']:22s} {r['sensor']:6s} {r['coverage']:7s} {r['magnitude']:9.4g} {r['seed']:5d} -> "
              f"{r['cause']:18s} {100 * r['shrink']:5.0f} %  {r['where']:18s} "
              + "  ".join(f"{n} {100 * x:.0f}" for n, x, _ in r.get("ranking", [])))
    table, png = _confusion(rows, args.out)
    print("\nconfusion matrix (rows: withheld, columns: diagnosed)\n" + table + f"\n(also {png})")
    eff_rows = [r for r in rows if r["effect"] != "none"]
    hit = [_label(r["sensor"], r["effect"], r["has_temp"]) == r["cause"] for r in eff_rows]
    strict = [_strict_hit(r) for r in eff_rows]
    strict_rate = 100 * float(np.mean(strict)) if strict else 0.0
    observable = [r for r in eff_rows if _label(r["sensor"], r["effect"]) != "none"]
    top1 = float(np.mean(hit)) if hit else 0.0
    med_shrink = float(np.median([r["shrink"] for r in observable])) if observable else 0.0
    none_rows = [r for r in rows if r["effect"] == "none"]
    none_rate = float(np.mean([r["cause"] == "none" for r in none_rows])) if none_rows else 0.0
    print(f"\ntop-1 accuracy {100 * top1:.1f} % ({sum(hit)}/{len(hit)}; equivalent effects as one, misalignment -> none)"
          f"  target >= 90 %")
    print(f"  strict: top-ranked effect is the withheld one (its registry group) in {strict_rate:.1f} % "
          f"({sum(strict)}/{len(strict)}), bias drift / temperature without a temperature column not merged")
    print(f"median shrink {100 * med_shrink:.1f} % over {len(observable)} observable-effect recordings  target >= 80 %")
    print(f"none on baseline-only {100 * none_rate:.1f} % ({len(none_rows)} recordings)  target >= 90 %")
    failed = sum(r["cause"] in ("error", "traceback") for r in rows)
    print(f"no verdict (an exception instead): {failed} of {len(rows)} recordings  target 0")
    print(f"median time per diagnosis {np.median([r['seconds'] for r in rows]):.1f} s "
          f"({len(jobs)} recordings of {jobs[0][5]:.0f} s at 50 Hz)")
    real = []
    if args.no_real:
        print("\nreal recordings: skipped (--no-real)")
    elif args.real_dir.is_dir():
        print(f"\nreal recordings ({args.real_dir}): effect fitted on the first half, gap on the withheld half")
        real = _real(args.real_dir, args.out, args.quick)
    else:
        print(f"\nreal recordings: {args.real_dir} absent, skipped")
    secs = None if args.no_speed else _speed()  # None: JSON null, not NaN
    if args.no_speed:
        print("\nspeed: skipped (--no-speed)")
    else:
        print(f"\nspeed: one diagnosis of a 5-minute 100 Hz recording (30000 samples) took {secs:.1f} s (target < 60 s)")
    (args.out / "results.json").write_text(json.dumps({"rows": rows, "top1": top1, "top1_strict": strict_rate / 100,
                                                      "median_shrink": med_shrink,
                                                      "none_rate": none_rate, "real": real, "speed_s": secs}, indent=1))
    ok = top1 >= 0.9 and med_shrink >= 0.8 and none_rate >= 0.9
    if subset:
        print("(a subset of the benchmark: the targets apply to the full run)")
    return 0 if ok else 1
