"""Coverage benchmark: stream-path cost, incremental indicators against a rebuild, bounded memory.

Run ``margcal bench coverage [--quick]`` or ``python scripts/bench_coverage.py [--quick]``. Every
ratio is measured in the same run. Sections:

1. Memory: peak RSS (``resource.getrusage``) after 10^5 and 10^7 offered samples (10^6 with
   ``--quick``); the buffer is bounded, so the two should match. Run first, so that the larger
   arrays of the other sections do not set the process's peak.
2. Streaming path: median cost of ``DirectionBuffer.push`` per offered sample of a 100 Hz
   magnetometer stream turning at about 25 deg/s, after a warm-up that fills the bins (so most
   samples land in full bins and are refused by the per-bin interval). Target: <= 5 µs.
   The inactivity gate's per-sample cost is shown beside it (no target; O(1) amortised).
3. Per accepted sample at about 1000 buffered points: ``push`` (insert + evict) plus
   ``indicators()``, including the incremental hull, against ``compute_indicators`` from scratch on
   the same buffer. Targets: <= 1 ms and >= 10x faster.
4. Olivares et al. 2013, Fig. 7: C and D of a well-distributed and an axis-ellipses set of the same
   size (C close, D apart), beside the paper's values.
5. Inactivity gate on simulated tumbling (rests of 3–8 s): precision and recall of still detection,
   norm error of the emitted samples against the noise floor.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ..coverage.buffer import DirectionBuffer
from ..coverage.gate import InactivityGate
from ..coverage.indicators import compute_indicators
from ..sim.simulation import directions, random_sensor, tumbling, tumbling_motion

__all__ = [
    "CENTER", "RADIUS", "RATE_HZ", "bench_accepted", "bench_memory", "bench_offered", "fig7", "gate_on_tumbling",
    "main"
]

Array = np.ndarray

CENTER = np.array([12.0, -7.5, 30.0])  # raw magnetometer offset, µT
RADIUS = 48.0  # field norm, µT
RATE_HZ = 100.0


def _stream(
    rng: np.random.Generator, t0: float, n: int, phase: Array, rate_dps: float = 25.0
) -> tuple[list[float], list[list[float]]]:
    """``n`` samples from ``t0`` of a field seen by a body turning about slowly wandering axes."""
    t = t0 + np.arange(n) / RATE_HZ
    w = np.radians(rate_dps) * np.array([1.0, 0.61, 0.37])
    rot = Rotation.from_euler("ZYX", phase + t[:, None] * w)
    xyz = CENTER + RADIUS * rot.inv().apply([0.6, 0.0, 0.8]) + rng.normal(scale=0.005 * RADIUS, size=(n, 3))
    return t.tolist(), xyz.tolist()


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _current_rss_mib() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * resource.getpagesize() / 2**20
    except OSError:
        return float("nan")


def bench_offered(rng: np.random.Generator, n: int) -> dict[str, float]:
    """Median µs per offered sample of a dense stream into a warmed-up buffer."""
    buf = DirectionBuffer(center=CENTER, radius=RADIUS)
    phase = rng.uniform(0, 2 * np.pi, 3)
    t, xyz = _stream(rng, 0.0, 360_000, phase)  # one hour of warm-up at 100 Hz
    for ti, v in zip(t, xyz, strict=True):
        buf.push(ti, v)
    t, xyz = _stream(rng, 3600.0, n, phase)
    full = np.array(buf.bin_counts()) >= buf.per_bin
    full_hits = sum(bool(full[buf.bin_of(v)]) for v in xyz[:20_000])
    kept0 = buf.stats()["kept"]
    dt = np.empty(n)
    clock = time.perf_counter_ns
    push = buf.push
    for i in range(n):
        a = clock()
        push(t[i], xyz[i])
        dt[i] = clock() - a
    kept = buf.stats()["kept"] - kept0
    gate = InactivityGate()
    gt = np.empty(n)
    gpush = gate.push
    for i in range(n):
        a = clock()
        gpush(t[i], xyz[i])
        gt[i] = clock() - a
    return {
        "median_us": float(np.median(dt)) / 1e3,
        "p90_us": float(np.percentile(dt, 90)) / 1e3,
        "mean_us": float(dt.mean()) / 1e3,
        "kept_frac": kept / n,
        "full_bin_frac": full_hits / min(n, 20_000),
        "bins_full": float(full.mean()),
        "gate_median_us": float(np.median(gt)) / 1e3,
        "gate_mean_us": float(gt.mean()) / 1e3,
    }


def bench_accepted(rng: np.random.Generator, n_updates: int, n_batch: int) -> dict[str, float]:
    """Per accepted sample at ~1000 points: incremental update against the from-scratch computation."""
    buf = DirectionBuffer(center=CENTER, radius=RADIUS, min_interval_s=0.0)
    d = rng.normal(size=(4000 + n_updates, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = (CENTER + RADIUS * d + rng.normal(scale=0.01 * RADIUS, size=d.shape)).tolist()
    for i in range(4000):
        buf.push(float(i), pts[i])
    buf.indicators()
    rebuilds0 = buf.stats()["hull_rebuilds"]
    inc = np.empty(n_updates)
    batch: list[float] = []
    every = max(1, n_updates // n_batch)
    worst = 0.0
    for k in range(n_updates):
        a = time.perf_counter()
        buf.push(4000.0 + k, pts[4000 + k])
        ind = buf.indicators()
        inc[k] = time.perf_counter() - a
        if k % every == 0:
            p = buf.points()
            a = time.perf_counter()
            ref = compute_indicators(p, CENTER, RADIUS)
            batch.append(time.perf_counter() - a)
            worst = max(worst, abs(ind.D - ref.D) / ref.D, abs(ind.A - ref.A) / max(ref.A, 1e-12))
            worst = max(worst, float(ind.B != ref.B))
    b = np.array(batch)
    return {
        "n_points": float(len(buf)),
        "inc_median_us": float(np.median(inc)) * 1e6,
        "inc_mean_us": float(inc.mean()) * 1e6,
        "inc_p99_us": float(np.percentile(inc, 99)) * 1e6,
        "batch_median_us": float(np.median(b)) * 1e6,
        "batch_mean_us": float(b.mean()) * 1e6,
        "ratio_median": float(np.median(b) / np.median(inc)),
        "ratio_mean": float(b.mean() / inc.mean()),
        "max_rel_diff": worst,
        "hull_rebuilds": float(buf.stats()["hull_rebuilds"] - rebuilds0),
        "hull_vertices": float(buf.stats()["hull_vertices"]),
    }


def bench_memory(rng: np.random.Generator, checkpoints: list[int]) -> list[tuple[int, float, int, float]]:
    """(offered, peak RSS MiB, buffered, seconds) after each checkpoint of one long stream."""
    buf = DirectionBuffer(center=CENTER, radius=RADIUS)
    phase = rng.uniform(0, 2 * np.pi, 3)
    out = []
    done = 0
    chunk = 10_000  # small chunks, dropped before the next is made: the stream itself costs ~2 MiB
    start = time.perf_counter()
    push = buf.push
    for target in checkpoints:
        while done < target:
            m = min(chunk, target - done)
            t, xyz = _stream(rng, done / RATE_HZ, m, phase)
            for ti, v in zip(t, xyz, strict=True):
                push(ti, v)
            del t, xyz
            done += m
            if done % 100_000 == 0:
                print(f"\r  offered {done:,}", end="", file=sys.stderr, flush=True)
        out.append((done, _rss_mib(), len(buf), time.perf_counter() - start))
    print(file=sys.stderr)
    return out


def fig7(rng: np.random.Generator, n: int = 1000) -> tuple[object, object]:
    """Indicators of a well-distributed set and an axis-ellipses set of the same size (Olivares Fig. 7)."""

    c, r = np.array([512.0, 500.0, 520.0]), 260.0  # a 10-bit magnetometer like the paper's
    well = c + r * directions("uniform", n, rng) + rng.normal(scale=2.0, size=(n, 3))
    ill = c + r * directions("axis_ellipses", n, rng) + rng.normal(scale=2.0, size=(n, 3))
    return compute_indicators(well, c, r), compute_indicators(ill, c, r)


def gate_on_tumbling(rng: np.random.Generator, duration_s: float) -> dict[str, float]:
    """Precision/recall of still detection and norm error of emitted samples on simulated tumbling."""

    truth = random_sensor(rng, kind="accel")
    noise = 0.002
    motion = tumbling_motion(duration_s, RATE_HZ, rng, still_s=(3.0, 8.0))
    rec = tumbling(truth, duration_s, RATE_HZ, rng, motion=motion, noise=noise)
    gate = InactivityGate()
    det = np.zeros(rec.t.size, dtype=bool)
    emitted = []
    for i in range(rec.t.size):
        e = gate.push(rec.t[i], rec.raw[i])
        if gate.is_still:
            det[np.searchsorted(rec.t, gate.still_since) : i + 1] = True
        if e is not None:
            emitted.append(e)
    hit = det & rec.still
    err = np.abs(np.linalg.norm(truth.apply(np.array(emitted)), axis=1) - truth.norm)
    return {
        "precision": float(hit.sum() / det.sum()),
        "recall": float(hit.sum() / rec.still.sum()),
        "emitted": float(len(emitted)),
        "max_norm_err": float(err.max()),
        "noise_floor": noise * truth.norm,
    }


def _verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def main(argv: list[str] | None = None) -> int:
    """Run the coverage benchmark; print figures and ratios measured in this run."""
    parser = argparse.ArgumentParser(prog="margcal bench coverage", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (memory up to 10^6 samples)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.seed < 0:  # one line, as the CLI's (not numpy's traceback)
        parser.exit(2, f"{parser.prog}: error: --seed must be a non-negative integer, got {args.seed}\n")
    rng = np.random.default_rng(args.seed)
    quick = args.quick
    all_ok = True

    print("== 1. memory over a long stream (peak RSS; run first so earlier sections do not set the peak) ==")
    marks = [100_000, 1_000_000] if quick else [100_000, 10_000_000]
    rows = bench_memory(rng, marks)
    for n, rss, kept, secs in rows:
        print(f"  after {n:>12,} offered: peak RSS {rss:7.1f} MiB, buffered {kept}, {secs:6.1f} s")
    print(f"  (current RSS now {_current_rss_mib():.1f} MiB)")
    growth = rows[-1][1] - rows[0][1]
    ok = growth < 10.0
    all_ok &= ok
    print(f"  growth {growth:+.1f} MiB ({rows[-1][1] / rows[0][1]:.3f}x): flat {_verdict(ok)}")

    print("== 2. streaming path, per offered sample (100 Hz stream, warmed-up buffer) ==")
    o = bench_offered(rng, 100_000 if quick else 1_000_000)
    ok = o["median_us"] <= 5.0
    all_ok &= ok
    print(f"  DirectionBuffer.push: median {o['median_us']:.2f} µs, p90 {o['p90_us']:.2f} µs, mean {o['mean_us']:.2f} µs")
    print(f"  offered samples kept {100 * o['kept_frac']:.2f} %; landing in full bins {100 * o['full_bin_frac']:.1f} %;"
          f" bins full {100 * o['bins_full']:.0f} %")
    print(f"  InactivityGate.push:  median {o['gate_median_us']:.2f} µs, mean {o['gate_mean_us']:.2f} µs")
    print(f"  target median <= 5 µs: {_verdict(ok)}")

    print("== 3. per accepted sample at ~1000 buffered points (insert + evict + indicators, hull included) ==")
    a = bench_accepted(rng, 1000 if quick else 5000, 30 if quick else 100)
    ok = a["inc_median_us"] <= 1000.0 and a["ratio_median"] >= 10.0
    all_ok &= ok
    print(f"  buffered points {a['n_points']:.0f}, hull vertices {a['hull_vertices']:.0f},"
          f" full hull rebuilds {a['hull_rebuilds']:.0f}")
    print(f"  incremental: median {a['inc_median_us']:.0f} µs, mean {a['inc_mean_us']:.0f} µs, p99 {a['inc_p99_us']:.0f} µs")
    print(f"  from scratch (compute_indicators): median {a['batch_median_us']:.0f} µs, mean {a['batch_mean_us']:.0f} µs")
    print(f"  speed-up: {a['ratio_median']:.1f}x (medians), {a['ratio_mean']:.1f}x (means); "
          f"largest relative difference to the batch values {a['max_rel_diff']:.1e}")
    print(f"  targets <= 1 ms and >= 10x: {_verdict(ok)}")

    print("== 4. Olivares et al. 2013 Fig. 7: well-distributed vs axis ellipses, n = 1000 each ==")
    iw, ii = fig7(rng)
    print(f"  C_well = {iw.C:.0f}, C_ill = {ii.C:.0f} (ratio {ii.C / iw.C:.3f}); paper 3113 / 2954 (0.949)")
    print(f"  D_well = {iw.D:.4g}, D_ill = {ii.D:.4g} (ratio {ii.D / iw.D:.3f}); paper 4.9196e8 / 3.9166e8 (0.796)")
    print(f"  normalised: c_norm {iw.c_norm:.3f} / {ii.c_norm:.3f}, d_norm {iw.d_norm:.3f} / {ii.d_norm:.3f}")

    print("== 5. inactivity gate on simulated tumbling (rests 3–8 s, noise 0.2 % of g) ==")
    g = gate_on_tumbling(rng, 120.0 if quick else 600.0)
    ok = g["precision"] >= 0.97 and g["recall"] >= 0.9 and g["max_norm_err"] <= 3 * g["noise_floor"]
    all_ok &= ok
    print(f"  precision {g['precision']:.4f}, recall {g['recall']:.4f}, emitted {g['emitted']:.0f}")
    print(f"  max norm error of emitted samples {g['max_norm_err']:.4g} m/s² = "
          f"{g['max_norm_err'] / g['noise_floor']:.2f}x the noise floor {g['noise_floor']:.4g}")
    print(f"  targets precision >= 0.97, recall >= 0.9, error <= 3x floor: {_verdict(ok)}")
    print(f"all targets {'met' if all_ok else 'NOT met'}")
    return 0 if all_ok else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
