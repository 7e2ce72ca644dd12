"""Diagnosis on recordings it was not built from: the independent generator of ``tests/independent``.

Every case is made by ``tests/independent/generator.py`` (its own attitude, field, noise and effect
parametrisations; no code of the package), written as a ``t,x,y,z`` CSV in tesla and diagnosed the
way ``margcal diagnose CASE --sensor mag --norm 4.8e-05`` does (the shipped validator included). The
truth label is the generator's effect mapped to what a correct diagnosis names:

- ``soft_iron`` -> ``ellipsoid_shape`` (the package groups soft iron and non-orthogonality),
- ``bias_drift`` -> ``slow_drift`` (bias drift or temperature, no temperature column),
- ``temperature`` -> ``temperature`` (the generator writes the temperature column),
- ``misalignment`` -> ``none`` (a rotation of the sensor axes is invisible to magnitudes),
- the others by name (``quantization``, ``saturation``, ``nonlinearity``, ``hard_iron_jump``, ``none``).

With ``--shape-tolerance F`` the diagnosis counts a sensor shape (root sum of squares of the three cross-axis
terms of the symmetric W, relative to its diagonal) up to F as the sensor's own. The generator's draws do not
know F: a soft-iron case may end with a total shape within F (its added matrix partly cancels the sensor's own),
and a baseline sensor may exceed it. Where the generated sensor's shape (``true_shape``, from the generator's
truth, never from the diagnosis) and the label disagree, both ``none`` and ``ellipsoid_shape`` count (the
*accepted* answers); the strict score, the label alone, is printed beside it.

Split: the *tuning* cases (seeds 1-3, magnitude factor 1) are the only ones looked at while tuning;
the *held-out* cases (seeds 101-102, magnitude factors 0.6 and 1.6 of the generator's default) are only
reported; they were reported once before issue 15's second round was tuned, so that round adds a
*fresh* held-out set (seeds 201-203, factors 0.8 and 1.3), run once after its tuning was frozen. Both have
been seen since; the third round adds a *new* held-out set (seeds 401-403, factors 0.7 and 1.45), run once
after its tuning (on the tuning cases only) was frozen, and seen since. The fourth round adds a *final*
held-out set (seeds 501-503, factors 0.75 and 1.4), run once, with ``--part all``, after that round's
tuning (on the tuning cases only) was frozen. That round's change (a band twin's slow noise) raised the
tuning part from 90.7 to 94.4 % but not the held-out ones (final 87.0 %; the earlier held-out parts 127 ->
125 of 144), so it was not kept; the final part was then run once on the diagnosis without it: 87.0 % too.
The fifth round (no tuning of the diagnosis; the scoring of shapes within the tolerance above) adds a *last*
held-out set (seeds 901-903, factors 0.65 and 1.5), run once with ``--part all``. Two diagnosis changes of that
round (a step against a drift on the step evidence; the ``residual_cubic`` stage) were developed on other seeds
(1101-1212) and each run once on every part before it was merged; the *check* set (seeds 951-953, factors 0.85
and 1.25) was then added and run once on the merged code.
Rough motion (issue 27): the parts ``rough_tune`` (seeds 11-12, looked at while tuning) and ``rough`` (seeds
1301-1303, factors 0.8 and 1.25, reported only) generate the same effects with attitude steps of a few degrees per
sample at 50 Hz (``ROUGH``, ``tests/independent/rough_motion.py``: a fast-turning, vibrating platform); ``all``
leaves them out. The ``residual_cubic`` stage's Wald test with the residual's own noise model (a later round of issue
27) was developed on ``rough_tune``, its seeds 21-32 (``--seeds``) and band recordings of seeds 2001-2020 made
outside this script, then ``rough`` was run once. ``--command-timing`` times the whole ``margcal diagnose``
command (a new process, its imports, the validator's retraining and the report included) idle and with the
other core kept busy (``--no-plots``: the command's report without its figures). ``--seeds 1401-1403`` runs a
part's cases on other seeds (its magnitude factors and motion kept): a new set, run once.
``--part tune|held|fresh|new|final|last|check|rough_tune|rough|all``. Prints the
top-1 of each part, the confusion matrix (also ``confusion_independent.png``), tracebacks (must be 0) and
the time per diagnosis.

Usage::

    OMP_NUM_THREADS=1 python scripts/bench_diagnosis_independent.py --part all --out bench_out/independent
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import runpy
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
from study_ground_robot import independent_generator  # scripts/ is on the path when a script in it runs

from ros_margcal.bench.diagnosis import _confusion_plot
from ros_margcal.diagnosis import diagnose
from ros_margcal.recordings.read import read_recording
from ros_margcal.validation.shipped import load_default_validator

LABEL = {"none": "none", "soft_iron": "ellipsoid_shape", "nonlinearity": "nonlinearity", "temperature": "temperature",
         "saturation": "saturation", "quantization": "quantization", "bias_drift": "slow_drift",
         "misalignment": "none", "hard_iron_jump": "hard_iron_jump"}
MOTIONS = ("tumble", "band")
TUNE_SEEDS = (1, 2, 3)
HELD_SEEDS = (101, 102)
TUNE_FACTORS = (1.0,)
HELD_FACTORS = (0.6, 1.6)
FRESH_SEEDS = (201, 202, 203)
FRESH_FACTORS = (0.8, 1.3)
NEW_SEEDS = (401, 402, 403)
NEW_FACTORS = (0.7, 1.45)
FINAL_SEEDS = (501, 502, 503)
FINAL_FACTORS = (0.75, 1.4)
LAST_SEEDS = (901, 902, 903)
LAST_FACTORS = (0.65, 1.5)
CHECK_SEEDS = (951, 952, 953)
CHECK_FACTORS = (0.85, 1.25)
ROUGH_TUNE_SEEDS = (11, 12)
ROUGH_SEEDS = (1301, 1302, 1303)
ROUGH_FACTORS = (0.8, 1.25)
SPLITS = {"tune": (TUNE_SEEDS, TUNE_FACTORS), "held": (HELD_SEEDS, HELD_FACTORS), "fresh": (FRESH_SEEDS, FRESH_FACTORS),
          "new": (NEW_SEEDS, NEW_FACTORS), "final": (FINAL_SEEDS, FINAL_FACTORS), "last": (LAST_SEEDS, LAST_FACTORS),
          "check": (CHECK_SEEDS, CHECK_FACTORS), "rough_tune": (ROUGH_TUNE_SEEDS, TUNE_FACTORS),
          "rough": (ROUGH_SEEDS, ROUGH_FACTORS)}
"""part -> (seeds, magnitude factors of the generator's default)."""
ROUGH = {"tumble": (2.0, 2), "band": (5.0, 2)}
"""Rough-motion parts (``rough_tune``: looked at while tuning; ``rough``: reported only): motion -> (speedup,
shuffle) of ``tests/independent/rough_motion.generate_rough``: the tumble turns twice, the band five times as
fast, and consecutive pairs of samples are swapped at random (a vibrating platform), attitude steps of about
5 and 2.6 degrees per sample at 50 Hz (medians)."""


def generate_case(part: str, effect: str, magnitude: float, motion: str, seed: int, duration: float) -> dict[str, Any]:
    """The generator's recording of one case; on a rough part with the motion of ``ROUGH``."""
    if part.startswith("rough"):
        speedup, shuffle = ROUGH[motion]
        return GENERATE_ROUGH(GEN, "mag", motion, duration, 50.0, seed, speedup=speedup, shuffle=shuffle,
                                        effect=effect, magnitude=magnitude)
    return GEN.generate("mag", motion, duration, 50.0, seed, effect=effect, magnitude=magnitude)


SHAPE_TOLERANCE = 0.0
"""``--shape-tolerance``: cross-axis terms the diagnosis counts as the sensor's baseline (set by ``main``)."""


GEN = independent_generator()
GENERATE_ROUGH = runpy.run_path(str(Path(__file__).resolve().parents[1] / "tests" / "independent" / "rough_motion.py"))[
    "generate_rough"]


def jobs(part: str, duration: float, seeds_override: tuple[int, ...] = ()) -> list[tuple[str, str, float, str, int, float]]:
    """(part, effect, magnitude, motion, seed, duration) of every case of ``part`` (its seeds, or ``seeds_override``
    with the part's magnitude factors and motion)."""
    out = []
    parts = tuple(p for p in SPLITS if not p.startswith("rough")) if part == "all" else (part,)
    for p in parts:
        seeds, factors = SPLITS[p]
        seeds = seeds_override or seeds
        for k, seed in enumerate(seeds):
            for motion in MOTIONS:
                for effect in GEN.EFFECTS:
                    f = factors[(k + MOTIONS.index(motion)) % len(factors)]
                    m = f * GEN.DEFAULT_MAGNITUDE[effect]
                    if effect == "saturation":  # a clip level: the held-out levels stay below the field
                        m = min(GEN.DEFAULT_MAGNITUDE[effect] * (1.0 if f == 1.0 else (0.95 if f < 1 else 0.8)), 0.95)
                    out.append((p, effect, m, motion, seed, duration))
    return out


def true_shape(w_sym: np.ndarray) -> float:
    """The sensor shape the diagnosis's tolerance is about: root sum of squares of the three cross-axis terms of
    the symmetric ``W`` scaled by its diagonal (``diagnosis.baseline_noise.shaped_truth``'s definition)."""
    w = np.asarray(w_sym, dtype=float)
    d = np.sqrt(np.abs(np.diag(w)))
    c = w / np.outer(d, d)
    return float(np.sqrt(np.sum(np.triu(0.5 * (c + c.T), 1) ** 2)))


def accepted(label: str, shape: float, tolerance: float) -> list[str]:
    """The answers that count: the label; with a shape tolerance, also ``none`` for a shape-effect case whose
    generated shape is within it, and ``ellipsoid_shape`` for a shape-free case whose sensor exceeds it."""
    if tolerance > 0 and label == "ellipsoid_shape" and shape <= tolerance:
        return [label, "none"]
    if tolerance > 0 and label == "none" and shape > tolerance:
        return [label, "ellipsoid_shape"]
    return [label]


def case(job: tuple[str, str, float, str, int, float]) -> dict[str, Any]:
    """Generate, write, read back and diagnose one case; never raises."""
    part, effect, magnitude, motion, seed, duration = job
    row: dict[str, Any] = {"part": part, "effect": effect, "magnitude": magnitude, "motion": motion, "seed": seed,
                           "truth": LABEL[effect]}
    rec = generate_case(part, effect, magnitude, motion, seed, duration)
    row["true_shape"] = true_shape(rec["truth"]["W_sym"])
    row["accepted"] = accepted(row["truth"], row["true_shape"], SHAPE_TOLERANCE)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.csv"
        GEN.write_csv(path, rec)
        t0 = time.monotonic()
        try:
            r = read_recording(path, sensor="mag")
            d = diagnose(r, sensor="mag", norm=float(rec["truth"]["norm"]), validator=load_default_validator(),
                         shape_tolerance=SHAPE_TOLERANCE)
            row.update(cause=d.cause, best=d.best.name if d.best else "", shrink=d.shrink, where=d.where,
                       gap_before=d.gap_before, skipped=d.skipped,
                       ranking=[[f.name, round(f.shrink, 3), f.magnitude] for f in d.effects[:3]])
        except Exception as exc:  # a traceback is a failure of the benchmark, counted separately
            row.update(cause="traceback", best="", shrink=0.0, where=f"{type(exc).__name__}: {exc}"[:200],
                       traceback=traceback.format_exc()[-1500:])
        row["seconds"] = time.monotonic() - t0
    return row


def _busy() -> None:
    while True:
        pass


def timing(quick: bool) -> dict[str, float]:
    """Seconds of one diagnosis (validator stage included) of a 60 s, 50 Hz independent recording and of the
    package's 5-minute, 100 Hz speed recording, with one core kept busy by a spinning process meanwhile."""
    from ros_margcal.bench.diagnosis import speed_recording  # the package benchmark's own speed case

    hog = multiprocessing.get_context("fork").Process(target=_busy, daemon=True)
    hog.start()
    try:
        out = {}
        rec = GEN.generate("mag", "tumble", 60.0, 50.0, 7, effect="none")
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "case.csv"
            GEN.write_csv(path, rec)
            t0 = time.monotonic()
            diagnose(read_recording(path, sensor="mag"), sensor="mag", norm=float(rec["truth"]["norm"]),
                     validator=load_default_validator(), quick=quick)
            out["independent_60s_50Hz"] = time.monotonic() - t0
        long = speed_recording()
        t0 = time.monotonic()
        diagnose(long, sensor="mag", validator=load_default_validator(), quick=quick)
        out["package_5min_100Hz"] = time.monotonic() - t0
    finally:
        hog.terminate()
        hog.join()
    return out


def command_timing(quick: bool, busy: bool, plots: bool = True) -> float:
    """Wall time of one whole ``margcal diagnose`` command (a new process) on a 60 s, 50 Hz independent
    recording, optionally with the other core kept busy by a spinning process (``plots``: the report's figures)."""
    rec = GEN.generate("mag", "tumble", 60.0, 50.0, 7, effect="none")
    hog = multiprocessing.get_context("fork").Process(target=_busy, daemon=True)
    if busy:
        hog.start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "case.csv"
            GEN.write_csv(path, rec)
            cmd = [sys.executable, "-m", "ros_margcal", "diagnose", str(path), "--sensor", "mag", "--norm",
                   f"{float(rec['truth']['norm']):.6g}", "--out", str(Path(tmp) / "out"), *(["--quick"] if quick else []),
                   *([] if plots else ["--no-plots"])]
            t0 = time.monotonic()
            subprocess.run(cmd, check=True, capture_output=True)
            return time.monotonic() - t0
    finally:
        if busy:
            hog.terminate()
            hog.join()


def _hit(r: dict[str, Any]) -> bool:
    return r["cause"] in r.get("accepted", [r["truth"]])


def _summary(rows: list[dict[str, Any]], name: str) -> str:
    if not rows:
        return f"{name}: no cases"
    hit = [_hit(r) for r in rows]
    strict = [r["cause"] == r["truth"] for r in rows]
    eff = [r for r in rows if r["truth"] != "none"]
    none = [r for r in rows if r["truth"] == "none"]
    return (f"{name}: top-1 {100 * np.mean(hit):.1f} % ({sum(hit)}/{len(hit)}; strict labels {100 * np.mean(strict):.1f} %, "
            f"{sum(strict)}/{len(strict)}), effects {100 * np.mean([_hit(r) for r in eff]) if eff else 0:.1f} %, "
            f"none/unobservable {100 * np.mean([r['cause'] == 'none' for r in none]) if none else 0:.1f} %, "
            f"tracebacks {sum(r['cause'] == 'traceback' for r in rows)}")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 when top-1 >= 90 % on every part run and there is no traceback."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=(*SPLITS, "all"), default="all")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per recording (50 Hz)")
    p.add_argument("--effects", default="", help="only these generator effects, comma-separated")
    p.add_argument("--motions", default="", help="only these motions, comma-separated")
    p.add_argument("--seeds", default="",
                   help="these seeds (comma-separated, A-B for a range) in place of the part's own, with its magnitude "
                        "factors and motion: a new set, run once")
    p.add_argument("--jobs", type=int, default=1, help="worker processes (the machine is shared: 1)")
    p.add_argument("--out", type=Path, default=Path("bench_out/independent"))
    p.add_argument("--shape-tolerance", type=float, default=0.05,
                   help="cross-axis terms that are the sensor's baseline (the generator's own soft iron: entries "
                        "up to 0.05); 0: the package simulator's baseline, offset and gains only")
    p.add_argument("--timing", action="store_true",
                   help="only time one 60 s / 50 Hz and one 5 min / 100 Hz diagnosis with the other core kept busy")
    p.add_argument("--quick", action="store_true", help="with --timing: time margcal diagnose --quick")
    p.add_argument("--no-plots", action="store_true", help="with --command-timing: time margcal diagnose --no-plots")
    p.add_argument("--command-timing", action="store_true",
                   help="only time the whole margcal diagnose command (60 s at 50 Hz), idle and with the other core busy")
    p.add_argument("--rescore", action="store_true",
                   help="no diagnosis: score the cases of OUT/rows.jsonl again (their diagnoses as saved) at --shape-tolerance")
    args = p.parse_args(argv)
    if args.command_timing:
        for busy in (False, True):
            secs = command_timing(args.quick, busy, plots=not args.no_plots)
            flags = (" --quick" if args.quick else "") + (" --no-plots" if args.no_plots else "")
            print(f"margcal diagnose{flags}, 60 s at 50 Hz: {secs:.1f} s, "
                  f"{'the other core kept busy' if busy else 'no extra load'}")
        return 0
    if args.timing:
        for name, secs in timing(args.quick).items():
            print(f"{name}: {secs:.1f} s{' (--quick)' if args.quick else ''}, one other core kept busy")
        return 0
    global SHAPE_TOLERANCE  # read by the worker processes (forked after this)
    SHAPE_TOLERANCE = args.shape_tolerance
    args.out.mkdir(parents=True, exist_ok=True)
    todo = jobs(args.part, args.duration, parse_seeds(args.seeds))
    if args.effects:
        todo = [j for j in todo if j[1] in args.effects.split(",")]
    if args.motions:
        todo = [j for j in todo if j[3] in args.motions.split(",")]
    log = args.out / "rows.jsonl"
    if args.rescore:
        return report(rescore(log, args.shape_tolerance), args.out, args.duration, 0.0)
    rows: list[dict[str, Any]] = []
    log.unlink(missing_ok=True)
    t0 = time.monotonic()
    with multiprocessing.get_context("fork").Pool(max(1, args.jobs)) as pool:
        for r in pool.imap_unordered(case, todo):
            rows.append(r)
            with log.open("a") as fh:
                fh.write(json.dumps(r, default=str) + "\n")
            print(f"{r['part']:5s} {r['effect']:15s} {r['magnitude']:7.4g} {r['motion']:7s} {r['seed']:4d} -> "
                  f"{r['cause']:16s} ({'ok' if _hit(r) else 'MISS, want ' + '|'.join(r['accepted'])}) "
                  f"shape {r['true_shape']:.3f} "
                  f"{r['seconds']:5.1f} s  {r['where'][:60]}  "
                  + "  ".join(f"{n} {100 * x:.0f}" for n, x, _ in r.get("ranking", [])), flush=True)
    return report(rows, args.out, args.duration, time.monotonic() - t0)


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds of ``--seeds``: comma-separated integers or ``A-B`` ranges (inclusive); empty: none."""
    out: list[int] = []
    for item in filter(None, (x.strip() for x in text.split(","))):
        lo, _, hi = item.partition("-")
        try:
            out.extend(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            sys.exit(f"--seeds: {item!r} is neither a seed nor a range A-B")
    return tuple(out)


def rescore(log: Path, tolerance: float) -> list[dict[str, Any]]:
    """The saved cases of a run (``rows.jsonl``), their accepted answers recomputed at ``tolerance`` from the
    generator's truth (the shape is regenerated when the run predates it)."""
    if not log.is_file():
        sys.exit(f"no saved run at {log}: run the benchmark with --out first")
    rows = []
    for line in log.read_text().splitlines():
        r = json.loads(line)
        if "true_shape" not in r:
            rec = GEN.generate("mag", r["motion"], 1.0, 50.0, r["seed"], effect=r["effect"], magnitude=r["magnitude"])
            r["true_shape"] = true_shape(rec["truth"]["W_sym"])
        r["accepted"] = accepted(r["truth"], r["true_shape"], tolerance)
        rows.append(r)
    return rows


def _row_label(r: dict[str, Any]) -> str:
    """The confusion matrix's row: the label, marked when its generated shape makes a second answer right too."""
    return r["truth"] if len(r.get("accepted", ())) < 2 else f"{r['truth']} (shape {'<=' if r['truth'] != 'none' else '>'} tol)"


def report(rows: list[dict[str, Any]], out: Path, duration: float, seconds: float) -> int:
    """Print the scores per part and motion, the confusion matrix (and its PNG) and the times; the exit code."""
    rows.sort(key=lambda r: (r["part"], r["effect"], r["motion"], r["seed"]))
    for part, (_, factors) in SPLITS.items():
        sel = [r for r in rows if r["part"] == part]
        if sel:  # the seeds run (``--seeds`` may replace the part's own)
            seeds = tuple(sorted({int(r["seed"]) for r in sel}))
            print(_summary(sel, f"{part:5s} (seeds {seeds}, magnitude factors {factors})"))
    for motion in MOTIONS:
        sel = [r for r in rows if r["motion"] == motion]
        if sel:
            print(_summary(sel, f"motion {motion}"))
    held = [r for r in rows if r["part"] != "tune"]
    if held and len(held) < len(rows):
        print(_summary(held, "held-out parts together"))
    print(_summary(rows, "all"))
    table, png = _confusion_plot([_row_label(r) for r in rows], [r["cause"] for r in rows], out,
                                 "confusion_independent.png", "generator effect (correct cause)")
    print("confusion matrix (rows: truth, columns: diagnosed)\n" + table + f"\n(also {png})")
    secs = [r["seconds"] for r in rows]
    print(f"time per diagnosis: median {np.median(secs):.1f} s, max {np.max(secs):.1f} s ({len(rows)} cases of "
          f"{duration:.0f} s at 50 Hz, {seconds:.0f} s in all)")
    for r in rows:
        if r["cause"] == "traceback":
            print(f"\nTRACEBACK {r['effect']} {r['motion']} {r['seed']}:\n{r['traceback']}", file=sys.stderr)
    ok = all(r["cause"] != "traceback" for r in rows) and np.mean([_hit(r) for r in rows]) >= 0.9
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
