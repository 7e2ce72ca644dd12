"""Study: does retraining the validator with a known effect bring its prediction closer to the measured error?

For each simulated effect at a KNOWN magnitude and several seeds, a magnetometer recording (smooth
motion, 120 s at 50 Hz, noise 0.5 %, as ``margcal simulate --pattern smooth``) is measured like
``margcal diagnose`` does it (``diagnosis.downstream``: a 300-sample set evenly spaced over the
recording, measured against the recording's best fit). Four validators predict its error: the
shipped one (``original``), one retrained with the true magnitude (``true``), with twice it (``2x``,
an overshooting diagnosis) and without the effect (``control``, same corpus size and seed); the
retraining corpora are built as ``margcal diagnose`` builds them (``compare_validators``: sets drawn
from a recording, at the recording's rest noise, magnetometers). ``none=0`` is a recording without
effects (all retrained validators are then the control).

Prints, per effect, the median measured error and per validator the median predicted error and the
mean ``|log10(measured / predicted)|`` over seeds, and how often ``true`` beats ``control``.

    OMP_NUM_THREADS=1 PYTHONPATH=. python scripts/study_downstream.py --seeds 4 --n-sets 400
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ros_margcal.diagnosis.downstream import N_SET, compare_validators, retrain_validator, validator_errors
from ros_margcal.diagnosis.twin import subsample
from ros_margcal.model.fitting import fit
from ros_margcal.sim.simulation import magnetometer_stream, random_sensor
from ros_margcal.validation.shipped import load_default_validator

DEFAULT_EFFECTS = "none=0,bias_drift=0.02,temperature=0.002,nonlinearity=0.02,disturbance=0.3,noise=0.005"
VALIDATORS = ("original", "true", "2x", "control")
NOISE = 0.005
"""Baseline white noise of the recordings, fraction of the norm (``margcal simulate``'s default)."""


def _recording_set(name: str, magnitude: float, seed: int, duration: float) -> dict[str, Any]:
    """The 300-sample set of a simulated recording and what ``validator_downstream`` takes from its
    diagnosis: the recording's best fit, the set's span, samples per set sample, the rest noise (the
    baseline noise, as ``margcal diagnose --rest-noise`` gives it: a noise effect comes on top)."""
    rng = np.random.default_rng([seed, 5])
    truth = random_sensor(rng, "mag")
    effects = {name: magnitude} if name != "none" else None
    rec = magnetometer_stream(truth, duration, 50.0, rng, noise=NOISE, effects=effects)
    sub = subsample(len(rec.raw), 6000)
    pts = rec.raw[sub]
    best = fit(pts, model="sym", method="lm", norm=None)
    pick = np.linspace(0, len(pts) - 1, min(N_SET, len(pts))).astype(np.intp)
    return {"points": pts[pick], "reference": best, "span_s": float(rec.t[sub][pick][-1] - rec.t[sub][pick][0]),
            "recording": max(2, round(len(pts) / len(pick))), "noise": NOISE, "kind": "mag"}


def run_case(name: str, magnitude: float, seed: int, n_sets: int, duration: float, *,
             corpus_noise: bool = True) -> dict[str, Any]:
    """One recording: measured error and the four validators' predictions (``none``: all retrained
    ones are the control). ``corpus_noise`` False: retraining sets at the corpus' random noise range."""
    validator = load_default_validator()
    s = _recording_set(name, magnitude, seed, duration)
    if not corpus_noise:
        s["noise"] = None
    pts, best = s["points"], s["reference"]
    opts = {"duration_s": s["span_s"], "recording": s["recording"], "noise": s["noise"], "kind": s["kind"]}
    if name == "none":
        predicted, measured = validator_errors(pts, best, validator)
        control, summary = retrain_validator(validator, n_sets, seed, None, **opts)
        p_ctrl = validator_errors(pts, best, control)[0]
        pred = {"original": predicted, "true": p_ctrl, "2x": p_ctrl, "control": p_ctrl}
        return {"effect": name, "magnitude": magnitude, "seed": seed, "measured": measured, "predicted": pred,
                "median_label": {"true": summary["median_label"], "control": summary["median_label"]}}
    cmp = compare_validators(pts, best, validator, {name: magnitude}, span_s=s["span_s"], recording=s["recording"],
                             noise=s["noise"], kind=s["kind"], n_sets=n_sets, seed=seed)
    v = cmp["validators"]
    over, _ = retrain_validator(validator, n_sets, seed, {name: 2.0 * magnitude}, **opts)
    pred_2x = validator_errors(pts, best, over)[0]
    pred = {"original": v["original"]["predicted"], "true": v["with_effect"]["predicted"], "2x": pred_2x,
            "control": v["control"]["predicted"]}
    return {"effect": name, "magnitude": magnitude, "seed": seed, "measured": cmp["measured"], "predicted": pred,
            "median_label": {"true": v["with_effect"]["median_label"], "control": v["control"]["median_label"]}}


def _table(rows: list[dict[str, Any]]) -> str:
    lines = [f"{'effect':<22}{'seeds':>6}{'measured':>10}" + "".join(f"{k + ' pred':>13}{'|log|':>7}" for k in VALIDATORS)
             + f"{'true<ctrl':>11}{'label true/ctrl':>17}"]
    for key in dict.fromkeys((r["effect"], r["magnitude"]) for r in rows):
        rs = [r for r in rows if (r["effect"], r["magnitude"]) == key]
        meas = np.array([r["measured"] for r in rs])
        cells = ""
        logs = {}
        for k in VALIDATORS:
            p = np.array([r["predicted"][k] for r in rs])
            logs[k] = np.abs(np.log10(meas / p))
            cells += f"{np.median(p):>13.2e}{logs[k].mean():>7.2f}"
        wins = int(np.sum(logs["true"] < logs["control"]))
        lab = np.median([r["median_label"]["true"] / r["median_label"]["control"] for r in rs])
        lines.append(f"{key[0] + '=' + format(key[1], 'g'):<22}{len(rs):>6}{np.median(meas):>10.2e}{cells}"
                     f"{f'{wins}/{len(rs)}':>11}{lab:>17.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the study and print the table."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--effects", default=DEFAULT_EFFECTS, help=f"name=magnitude,... (default {DEFAULT_EFFECTS})")
    p.add_argument("--seeds", type=int, default=4, help="recordings (and retraining corpus seeds) per effect")
    p.add_argument("--n-sets", type=int, default=400, help="sets per retraining corpus (diagnose's default 400)")
    p.add_argument("--duration", type=float, default=120.0, help="recording length, s")
    p.add_argument("--corpus-noise-range", action="store_true",
                   help="retrain at the corpus' random noise range, not at the recording's rest noise")
    p.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = p.parse_args(argv)
    effects = [(k, float(m)) for k, m in (item.split("=") for item in args.effects.split(",") if item)]
    rows = []
    t0 = time.monotonic()
    for i, (name, m) in enumerate(effects):
        for seed in range(args.seeds):
            rows.append(run_case(name, m, seed, args.n_sets, args.duration, corpus_noise=not args.corpus_noise_range))
            print(f"\r{i + 1}/{len(effects)} effects, seed {seed + 1}/{args.seeds}, {time.monotonic() - t0:.0f} s",
                  end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    print(f"downstream study: {args.seeds} seeds, {args.n_sets} sets per retraining corpus, smooth mag recordings "
          f"{args.duration:g} s at 50 Hz, noise 0.5 %, a {N_SET}-sample set each; retraining noise: "
          f"{'the corpus range 0.1-0.5 %' if args.corpus_noise_range else 'the recording rest noise'}")
    print("pred = median predicted error over seeds; |log| = mean |log10(measured/predicted)|; true<ctrl = seeds "
          "where retraining with the true magnitude beats the control; label true/ctrl = median ratio of the "
          "retraining corpora's median labels")
    print(_table(rows))
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
