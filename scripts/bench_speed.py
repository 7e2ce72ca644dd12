"""Benchmark (issue 28 item 3): how soon and how cheaply the streaming calibrator calibrates independent streams.

Every case drives ``SensorCalibrator.push`` sample by sample (as ``margcal replay`` and the node's worker do) on a
recording of the INDEPENDENT generator (tests/independent/generator.py: no code shared with the package) and
measures, per run:

- ``good s``: the stamp of the first published calibration whose 30 deg heading p95 (``generator.heading_p95``
  against the truth; after a hard-iron jump, against the truth after it) is <= 1 deg (tumble-like cases only);
- ``wrong``: published calibrations whose heading p95 at the tilt the motion covers (30 deg for the tumble,
  hemisphere and jump; 5 deg for the ground robot; 20 deg for the band) exceeds 5 deg, and ``kept s``: how long
  such calibrations stayed the current one in total;
- ``us/sa``: mean time per sample, all in (intake, buffer, evaluations, fits, and the status read every
  ``--status-every`` s of stream time, 1 s by default as the node's status period: a status computes the heading
  figures it shows when first read);
- ``max ms`` and ``p99 us``: the longest single ``push`` and the 99th percentile; ``st ms``: the longest status read.

A full pass of Python's garbage collector lands in whichever push happens to allocate when it is due: once in a
300 s ground robot it took 59 ms, traversing the ~73 000 objects of the imports (numpy, scipy) and the recording;
``--freeze`` calls ``gc.freeze()`` before driving (what ``margcal replay`` and the node's worker could do after
start-up), so those objects are not traversed again.

Times are the thread's CPU time (``time.thread_time``): on a shared CPU the wall time of a push also holds
the time other processes had the core, which is no cost of ours (``--wall`` measures wall time instead).

Baselines measured in the same run: ``intake`` (the same stream through ``Intake.take`` alone: the floor of any
sample path) and, with ``--base DIR`` (a checkout of another commit, e.g. ``git worktree add /tmp/k_base e0f5b2b``),
the calibrator of that checkout; both variants run in child processes, alternated ``--repeat`` times, and the
timing figures are medians over the repeats (the CPU is shared: compare ratios, not absolute figures).

Seeds: ``--seeds tuning`` (1-3, looked at while changing the calibrator) or ``reported`` (21-25, run only to
report; the default), or a comma list.
Run: ``python scripts/bench_speed.py [--base /tmp/k_base] [--seeds reported] [--repeat 3] [--quick]``;
``--profile CASE`` prints a cProfile of one case (seed 1) instead; ``--duration S`` makes every case S seconds long (the
cost on a long stream, once the first calibrations are paid for).
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import json
import math
import os
import pstats
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from study_ground_robot import independent_generator  # scripts/ is on the path when a script in it runs

from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator  # the variant on PYTHONPATH
from ros_margcal.stream.intake import Intake

TUNING = (1, 2, 3)
REPORTED = (21, 22, 23, 24, 25)
HARD = {"hard_iron_mag": 30e-6, "symmetric_soft_iron": True}
CASES: dict[str, tuple[dict[str, Any], float, bool]] = {
    "tumble-50": ({"motion": "tumble", "duration_s": 60.0, "rate_hz": 50.0}, 30.0, True),
    "tumble-100": ({"motion": "tumble", "duration_s": 60.0, "rate_hz": 100.0}, 30.0, True),
    "ground5-50": ({"motion": "ground", "duration_s": 300.0, "rate_hz": 50.0, "tilt_deg": 5.0}, 5.0, False),
    "band20-50": ({"motion": "band", "duration_s": 120.0, "rate_hz": 50.0, "band_deg": 20.0}, 20.0, False),
    "hemisphere-50": ({"motion": "hemisphere", "duration_s": 120.0, "rate_hz": 50.0}, 30.0, False),
    "jump-50": ({"motion": "tumble", "duration_s": 120.0, "rate_hz": 50.0, "effect": "hard_iron_jump",
                 "magnitude": 20e-6 / 48e-6, "t_jump": 60.0}, 30.0, True),
}
"""name -> (generator arguments, tilt judged for wrong acceptances in deg, first-good time measured)."""
QUICK = ("tumble-50", "ground5-50", "jump-50")
GOOD_DEG, WRONG_DEG = 1.0, 5.0
CLOCK = time.thread_time
"""The clock of the timings (``--wall``: ``time.perf_counter``)."""
FREEZE = False
"""``--freeze``: ``gc.freeze()`` once the recording is made, before the calibrator is driven (module docstring)."""
STATUS_EVERY_S = 1.0
"""Stream seconds between status reads (the node's status period; ``--status-every``, 0: none): a status computes
the heading figures it shows when first read, so its time is part of the cost."""


DURATION_S: float | None = None
"""``--duration``: every case this long instead (a long stream: the cost once the first calibrations are paid for)."""


def _record(gen: Any, name: str, seed: int) -> dict[str, Any]:
    args = {**CASES[name][0], **({"duration_s": DURATION_S} if DURATION_S else {})}
    return gen.generate("mag", seed=seed, gyro_scale=0.03, **HARD, **args)


def _truth_at(rec: dict[str, Any], t: float) -> dict[str, Any]:
    """The truth a calibration published at ``t`` is judged by (after a hard-iron jump: the one after it)."""
    tr = rec["truth"]
    t_jump = rec["meta"]["effect_params"].get("t_jump")
    if t_jump is None or t < t_jump:
        return tr
    return {**tr, "offset": tr["offset_after"]}


def _drive(rec: dict[str, Any], gyro: bool) -> tuple[np.ndarray, np.ndarray, list[Any]]:
    """Push every sample, and read the status every ``STATUS_EVERY_S`` of stream time (as the node does); per-push
    and per-status times (s, ``CLOCK``) and the published calibrations' events."""
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag"))
    g = rec["gyro"].tolist() if gyro else [None] * len(rec["t"])
    ts, xyz = rec["t"].tolist(), rec["xyz"].tolist()
    if FREEZE:  # the stream's own lists too (90 000 of them for 30 min: a full pass over them was the longest "push")
        gc.collect()
        gc.freeze()
    dts = np.empty(len(ts))
    sts = []
    events = []
    clock = CLOCK
    next_status = ts[0] + STATUS_EVERY_S if ts else 0.0
    for i, (t, v, w) in enumerate(zip(ts, xyz, g, strict=True)):
        t0 = clock()
        out = cal.push(t, v, w)
        dts[i] = clock() - t0
        if out:
            events += [e for e in out if e.kind is EventKind.CALIBRATED]
        if STATUS_EVERY_S > 0 and t >= next_status:
            t0 = clock()
            cal.status(t).to_dict()
            sts.append(clock() - t0)
            next_status = t + STATUS_EVERY_S
    return dts, np.array(sts), events


def _clock_cost(n: int = 20000) -> float:
    """What a timed push's figure holds besides the push (s): the figure of timing nothing, taken off the means."""
    dts = np.empty(n)
    clock = CLOCK
    for i in range(n):
        t0 = clock()
        dts[i] = clock() - t0
    return float(np.median(dts))


def _intake_only(rec: dict[str, Any], gyro: bool) -> float:
    """Mean time per sample (s, ``CLOCK``) of the intake alone on the same stream."""
    intake = Intake(PipelineConfig.for_sensor("mag"), use_gyro=gyro)
    g = rec["gyro"].tolist() if gyro else [None] * len(rec["t"])
    ts, xyz = rec["t"].tolist(), rec["xyz"].tolist()
    t0 = CLOCK()
    for t, v, w in zip(ts, xyz, g, strict=True):
        intake.take(t, v, w)
    return (CLOCK() - t0) / len(ts)


def score(gen: Any, rec: dict[str, Any], events: list[Any], tilt: float) -> dict[str, float]:
    """First good time, wrong acceptances and how long they stayed current (see the module docstring)."""
    good, wrong, kept = np.nan, 0, 0.0
    end = float(rec["t"][-1])
    for k, e in enumerate(events):
        tr = _truth_at(rec, e.t)
        c = e.calibration
        if np.isnan(good) and gen.heading_p95(c.matrix, c.offset, tr, 30.0) <= GOOD_DEG:
            good = e.t
        if gen.heading_p95(c.matrix, c.offset, tr, tilt) > WRONG_DEG:
            wrong += 1
            kept += (events[k + 1].t if k + 1 < len(events) else end) - e.t
    return {"good": good, "wrong": wrong, "kept": kept, "n_cal": len(events)}


def worker(cases: list[str], seeds: list[int]) -> None:
    """Run every (case, seed, gyro) with the package on sys.path; one JSON line per run on stdout."""
    gen = independent_generator()
    cost = _clock_cost()
    for name in cases:
        for seed in seeds:
            rec = _record(gen, name, seed)
            for gyro in (False, True):
                dts, sts, events = _drive(rec, gyro)
                all_in = (float(dts.sum()) + float(sts.sum())) / len(dts) - cost * (1.0 + len(sts) / len(dts))
                row = {"case": name, "seed": seed, "gyro": gyro, "us": 1e6 * all_in,
                       "max_ms": 1e3 * float(dts.max()), "p99_us": 1e6 * float(np.percentile(dts, 99)),
                       "status_ms": 1e3 * float(sts.max()) if len(sts) else 0.0,
                       "intake_us": 1e6 * _intake_only(rec, gyro), **score(gen, rec, events, CASES[name][1])}
                print(json.dumps(row), flush=True)


def _run_variant(pkg_root: str, cases: list[str], seeds: list[int]) -> list[dict[str, Any]]:
    env = dict(os.environ, PYTHONPATH=pkg_root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")  # the thread's CPU time is all of it
    cmd = [sys.executable, __file__, "--worker", "--cases", ",".join(cases), "--seeds", ",".join(map(str, seeds))]
    cmd += ["--wall"] if CLOCK is time.perf_counter else []
    cmd += ["--status-every", repr(STATUS_EVERY_S)] + (["--freeze"] if FREEZE else [])
    cmd += ["--duration", repr(DURATION_S)] if DURATION_S else []
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if out.returncode:
        sys.exit(f"the run with {pkg_root} failed:\n{out.stderr[-3000:]}")
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def _median_rows(reps: list[list[dict[str, Any]]]) -> dict[tuple[str, int, bool], dict[str, float]]:
    """Per (case, seed, gyro): the timing figures' medians over the repeats (the rest is deterministic)."""
    out: dict[tuple[str, int, bool], dict[str, float]] = {}
    for rows in zip(*reps, strict=True):
        r = dict(rows[0])
        for k in ("us", "max_ms", "p99_us", "intake_us", "status_ms"):
            r[k] = float(np.median([x.get(k, np.nan) for x in rows]))
        out[(r["case"], r["seed"], r["gyro"])] = r
    return out


def _table(new: dict[Any, dict[str, float]], base: dict[Any, dict[str, float]] | None) -> None:
    """One line per case and gyro: medians over the seeds, worst step, wrong acceptances, ratios to the baselines."""
    print(f"{'case':14s} {'gyro':4s} {'good s':>7s} {'wrong':>5s} {'kept s':>6s} {'us/sa':>6s} {'max ms':>6s} "
          f"{'st ms':>6s} {'p99 us':>7s} {'/intake':>7s}"
          + ("  | base: good s  wrong  us/sa  max ms  st ms   us ratio  max ratio" if base else ""))
    keys = sorted({(k[0], k[2]) for k in new}, key=lambda k: (list(CASES).index(k[0]), k[1]))
    for case, gyro in keys:
        rows = [v for k, v in new.items() if k[0] == case and k[2] == gyro]
        good = np.array([r["good"] for r in rows], float)
        us = np.median([r["us"] for r in rows])
        line = (f"{case:14s} {'yes' if gyro else 'no':4s} {_good(good):>7s} {sum(r['wrong'] for r in rows):5d} "
                f"{sum(r['kept'] for r in rows):6.1f} {us:6.1f} {max(r['max_ms'] for r in rows):6.1f} "
                f"{max(r['status_ms'] for r in rows):6.1f} {np.median([r['p99_us'] for r in rows]):7.0f} "
                f"{us / np.median([r['intake_us'] for r in rows]):7.1f}")
        if base:
            b = [v for k, v in base.items() if k[0] == case and k[2] == gyro]
            bus = np.median([r["us"] for r in b])
            bmax = max(r["max_ms"] for r in b)
            line += (f"  | {_good(np.array([r['good'] for r in b], float)):>12s} {sum(r['wrong'] for r in b):5d} "
                     f"{bus:6.1f} {bmax:7.1f} {max(r['status_ms'] for r in b):6.1f} {us / bus:9.2f} "
                     f"{max(r['max_ms'] for r in rows) / bmax:10.2f}")
        print(line)


def _good(v: np.ndarray) -> str:
    """Median first-good time over the seeds, and how many never got one."""
    if np.isnan(v).all():
        return "-"
    miss = int(np.isnan(v).sum())
    return f"{np.nanmedian(v):.1f}" + (f"({miss}x-)" if miss else "")


def profile(case: str, gyro: bool) -> None:
    """cProfile of one case, seed 1: where the push time goes."""
    rec = _record(independent_generator(), case, 1)
    prof = cProfile.Profile()
    prof.enable()
    _drive(rec, gyro)
    prof.disable()
    pstats.Stats(prof).sort_stats("cumulative").print_stats(35)


def main(argv: list[str] | None = None) -> int:
    global CLOCK, STATUS_EVERY_S, FREEZE, DURATION_S
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", help="a checkout of another commit: its calibrator is the baseline")
    ap.add_argument("--seeds", default="reported", help="tuning, reported or a comma list")
    ap.add_argument("--cases", default="", help="comma list of " + ", ".join(CASES))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    ap.add_argument("--profile", metavar="CASE", help="profile one case (seed 1) and stop")
    ap.add_argument("--gyro", action="store_true", help="with --profile: the gyro-aided calibrator")
    ap.add_argument("--wall", action="store_true", help="time wall clock, not the thread's CPU time")
    ap.add_argument("--status-every", type=float, default=STATUS_EVERY_S,
                    help="stream seconds between status reads (0: none)")
    ap.add_argument("--freeze", action="store_true",
                    help="gc.freeze() before driving: the start-up's objects out of the collector's full passes")
    ap.add_argument("--duration", type=float, metavar="S",
                    help="every case S seconds long (above the jump's 60 s): the cost on a long stream")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.wall:
        CLOCK = time.perf_counter
    STATUS_EVERY_S, FREEZE = a.status_every, a.freeze
    if a.duration is not None and not (math.isfinite(a.duration) and 60.0 < a.duration <= 86_400.0):
        sys.exit(f"--duration must be a number of seconds in (60, 86400], got {a.duration!r}")
    DURATION_S = a.duration
    seeds = list({"tuning": TUNING, "reported": REPORTED}.get(a.seeds) or map(int, a.seeds.split(",")))
    cases = a.cases.split(",") if a.cases else list(QUICK if a.quick else CASES)
    unknown = [c for c in cases + ([a.profile] if a.profile else []) if c not in CASES]
    if unknown:
        sys.exit(f"unknown case {', '.join(unknown)}; cases: {', '.join(CASES)}")
    if a.worker:
        worker(cases, seeds)
        return 0
    if a.profile:
        profile(a.profile, a.gyro)
        return 0
    here = str(Path(__file__).resolve().parents[1])
    news: list[list[dict[str, Any]]] = []
    bases: list[list[dict[str, Any]]] = []
    for _ in range(a.repeat):  # alternated, so both variants see the same load
        if a.base:
            bases.append(_run_variant(a.base, cases, seeds))
        news.append(_run_variant(here, cases, seeds))
    print(f"seeds {seeds}, {a.repeat} repeats (timings: medians of {'wall' if a.wall else 'CPU'} time; a status every "
          f"{STATUS_EVERY_S:g} s{', gc frozen' if FREEZE else ''}); "
          f"good: first 30 deg p95 <= {GOOD_DEG:g} deg; wrong: published with p95 > {WRONG_DEG:g} deg at the case's tilt; "
          "/intake: us/sa over the intake alone")
    _table(_median_rows(news), _median_rows(bases) if a.base else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
