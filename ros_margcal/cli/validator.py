"""``margcal build-corpus``, ``train-validator`` and ``evaluate-validator``.

The evaluation follows Olivares et al. 2013, §4: the corpus is split into two datasets (``group`` 0
and 1); every validator is trained on one and tested on the other, then the roles are swapped, and
each figure is reported as mean ± std over the two directions (Tables 1–3). Beside the paper's
validators, the coverage gates of other systems (``ros_margcal.baselines``) are scored on the same
test sets, and the rank correlation (Spearman) of each score with the true error is reported, since
the node shows the predicted error, not only the verdict.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from ..model.errors import ConfigError
from ..training.corpus import FEATURES, Corpus, build_corpus
from ..validation.baselines import BASELINES
from ..validation.fuzzy import FuzzyValidator
from ..validation.roc import evaluate_threshold, roc_auc, roc_curve
from ..validation.threshold import DEFAULT_MAX_ERROR, DEFAULT_MAX_FPR, ThresholdValidator
from . import check_paths, plot_file

__all__ = ["evaluate", "register", "train_fuzzy"]

DEFAULT_INPUTS = ("c_norm", "e_total")
"""Inputs of the shipped validator: normalised C and the set's total information (``coverage``).
The paper's pair, normalised C and D, is ``PAPER_INPUTS``; on withheld sets it scores ~0.985 AUC
against ~0.992 (README, issue 4) because C and D cannot tell two great circles from a sphere."""
PAPER_INPUTS = ("c_norm", "d_norm")
DEFAULT_CONSEQUENTS = "lsq"
PAPER_PAIRS = tuple(itertools.combinations(("A", "B", "C", "D"), 2))
NORM_PAIRS = tuple(itertools.combinations(("b_frac", "c_norm", "d_norm", "e_info", "e_total"), 2))
EXTRA_INPUTS = (("c_norm", "d_norm", "e_total"),)
ROC_INPUTS = (DEFAULT_INPUTS, PAPER_INPUTS, ("d_norm", "e_total"))
"""Fuzzy input sets whose ROC curves are kept in the results and plotted."""


def _ms(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"mean": float(np.nanmean(a)), "std": float(np.nanstd(a, ddof=1)) if a.size > 1 else 0.0}


def _spearman(pred_error: np.ndarray, true_error: np.ndarray) -> float:
    return float(spearmanr(pred_error, true_error).statistic)


def train_fuzzy(corpus: Corpus, inputs: tuple[str, ...] = DEFAULT_INPUTS, *, n_mf: int = 10, repeats: int = 10,
                max_error: float = DEFAULT_MAX_ERROR, max_fpr: float | None = DEFAULT_MAX_FPR, seed: int = 0,
                consequents: str = DEFAULT_CONSEQUENTS) -> FuzzyValidator:
    """Train a fuzzy validator on every set of ``corpus``."""
    v = FuzzyValidator(inputs, n_mf, max_error=max_error)
    v.fit(corpus.matrix(inputs), corpus.error, repeats=repeats, seed=seed, max_fpr=max_fpr, consequents=consequents)
    return v


def evaluate(corpus: Corpus, *, max_error: float = DEFAULT_MAX_ERROR, max_fpr: float | None = DEFAULT_MAX_FPR,
             pairs: tuple[tuple[str, ...], ...] | None = None, n_mf: int = 10, repeats: int = 10,
             seed: int = 0, progress: bool = False, consequents: str = DEFAULT_CONSEQUENTS) -> dict[str, Any]:
    """Train on one group, test on the other, swap; every figure per direction and mean ± std.

    Returns:
        A JSON-ready dict with ``single`` (Tables 1–2), ``fuzzy`` (Table 3), ``baselines`` and ``roc``
        (curve points of the default fuzzy model and of the baselines on each test group).
    """
    groups = [corpus.subset(corpus.group == g) for g in (0, 1)]
    for g, c in enumerate(groups):
        good = c.good(max_error)
        if good.all() or not good.any():
            msg = f"group {g} has {int(good.sum())} good sets of {len(c)}: both classes are needed; build a larger corpus"
            raise ConfigError(msg)
    pairs = pairs if pairs is not None else (*PAPER_PAIRS, *NORM_PAIRS, *EXTRA_INPUTS, PAPER_INPUTS, DEFAULT_INPUTS)
    pairs = tuple(dict.fromkeys(tuple(p) for p in pairs))
    out: dict[str, Any] = {"max_error": max_error, "max_fpr": max_fpr, "n_sets": len(corpus), "consequents": consequents,
                           "n_good": [int(c.good(max_error).sum()) for c in groups],
                           "n_sets_per_group": [len(c) for c in groups], "corpus_meta": corpus.meta,
                           "single": {}, "fuzzy": {}, "baselines": {}, "roc": {}}
    swaps = ((0, 1), (1, 0))
    for name in FEATURES:
        rows = []
        for tr, te in swaps:
            tv = ThresholdValidator(name, max_error=max_error).fit(groups[tr].column(name), groups[tr].error)
            assert tv.train_point is not None and tv.threshold is not None
            score_te = tv.score(groups[te].column(name))
            pos_te = groups[te].good(max_error)
            op = evaluate_threshold(score_te, pos_te, tv.threshold if tv.higher_is_better else -tv.threshold)
            rows.append({"train_group": tr, "threshold": tv.threshold, "train_sensitivity": tv.train_point.sensitivity,
                         "train_specificity": tv.train_point.specificity, "train_auc": tv.train_point.auc,
                         "sensitivity": op.sensitivity, "specificity": op.specificity, "auc_point": op.auc,
                         "auc": roc_auc(score_te, pos_te), "spearman": _spearman(-score_te, groups[te].error)})
        keys = ("train_auc", "auc_point", "auc", "spearman")
        out["single"][name] = {"runs": rows, **{k: _ms([r[k] for r in rows]) for k in keys}}
    live = sys.stderr.isatty()
    for k, inputs in enumerate(pairs):
        t0 = time.monotonic()
        rows = []
        for tr, te in swaps:
            v = train_fuzzy(groups[tr], inputs, n_mf=n_mf, repeats=repeats, max_error=max_error, max_fpr=max_fpr, seed=seed,
                            consequents=consequents)
            pred = v.predict(groups[te].matrix(inputs))
            pos_te = groups[te].good(max_error)
            assert v.threshold is not None
            op = evaluate_threshold(-pred, pos_te, -v.threshold)
            rows.append({"train_group": tr, "threshold": v.threshold, "sensitivity": op.sensitivity,
                         "specificity": op.specificity, "ill_accepted": op.ill_accepted, "auc_point": op.auc,
                         "auc": roc_auc(-pred, pos_te), "spearman": _spearman(pred, groups[te].error)})
            if inputs in ROC_INPUTS:
                fpr, tpr, _ = roc_curve(-pred, pos_te)
                out["roc"][f"fuzzy {'&'.join(inputs)} (test {te})"] = {"fpr": fpr.tolist(), "tpr": tpr.tolist()}
        key = "&".join(inputs)
        out["fuzzy"][key] = {"inputs": list(inputs), "runs": rows,
                             **{k2: _ms([r[k2] for r in rows]) for k2 in ("auc", "auc_point", "ill_accepted", "spearman")}}
        if progress:  # in place on a terminal, a line each in a log
            text = f"fuzzy {k + 1}/{len(pairs)} ({key}, {time.monotonic() - t0:.1f} s)"
            print(f"\r{text}   " if live else text, end="" if live else "\n", file=sys.stderr, flush=True)
    if progress and live:
        print(file=sys.stderr)
    for name, b in BASELINES.items():
        rows = []
        for _, te in swaps:
            raw = groups[te].column(name)
            pos_te = groups[te].good(max_error)
            score = b.oriented(raw)
            acc = b.accept(raw)
            sens = float((acc & pos_te).sum() / pos_te.sum())
            spec = float((~acc & ~pos_te).sum() / (~pos_te).sum())
            rows.append({"test_group": te, "threshold": b.default_threshold, "sensitivity": sens, "specificity": spec,
                         "ill_accepted": 1.0 - spec, "auc_point": (sens + spec) / 2, "auc": roc_auc(score, pos_te),
                         "spearman": _spearman(-score, groups[te].error)})
            fpr, tpr, _ = roc_curve(score, pos_te)
            out["roc"][f"{name} (test {te})"] = {"fpr": fpr.tolist(), "tpr": tpr.tolist()}
        out["baselines"][name] = {"description": b.description, "runs": rows,
                                  **{k: _ms([r[k] for r in rows]) for k in ("auc", "auc_point", "ill_accepted", "spearman")}}
    return out


def _pm(d: dict[str, float]) -> str:
    return f"{d['mean']:.4f} ± {d['std']:.4f}"


def format_tables(res: dict[str, Any]) -> str:
    """Tables 1–3 of Olivares et al. in text, plus the baselines."""
    lines = [f"{res['n_sets']} sets, good = error < {res['max_error']:.3%} "
             f"({res['n_good'][0]}/{res['n_sets_per_group'][0]} and {res['n_good'][1]}/{res['n_sets_per_group'][1]} good "
             f"in groups 0/1); threshold search capped at {res['max_fpr']} ill sets accepted for the fuzzy system", ""]
    lines.append("Table 1. Single-indicator thresholding, training (grid search for the best AUC)")
    lines.append(f"{'train':>5} {'ind.':>7} {'threshold':>12} {'sens':>7} {'spec':>7} {'AUC':>7}   average AUC")
    for name, d in res["single"].items():
        for i, r in enumerate(d["runs"]):
            tail = _pm(d["train_auc"]) if i == 0 else ""
            lines.append(f"{r['train_group'] + 1:>5} {name:>7} {r['threshold']:>12.4g} {r['train_sensitivity']:>7.4f} "
                         f"{r['train_specificity']:>7.4f} {r['train_auc']:>7.4f}   {tail}")
    lines += ["", "Table 2. Single-indicator thresholding, test on the other group (AUC of the threshold, and of the ROC)"]
    lines.append(f"{'train':>5} {'ind.':>7} {'threshold':>12} {'sens':>7} {'spec':>7} {'AUC@thr':>8} {'ROC AUC':>8} "
                 f"{'rho':>7}   average AUC@thr / ROC AUC")
    for name, d in res["single"].items():
        for i, r in enumerate(d["runs"]):
            tail = f"{_pm(d['auc_point'])} / {_pm(d['auc'])}" if i == 0 else ""
            lines.append(f"{r['train_group'] + 1:>5} {name:>7} {r['threshold']:>12.4g} {r['sensitivity']:>7.4f} "
                         f"{r['specificity']:>7.4f} {r['auc_point']:>8.4f} {r['auc']:>8.4f} {r['spearman']:>7.3f}   {tail}")
    lines += ["", f"Table 3. Fuzzy validator (zero-order TSK, consequents: {res.get('consequents', 'paper')}), "
              "test on the other group"]
    lines.append(f"{'train':>5} {'inputs':>22} {'max err':>8} {'opt thr':>8} {'sens':>7} {'spec':>7} {'ill acc':>8} "
                 f"{'ROC AUC':>8} {'rho':>7}   average ROC AUC")
    for key, d in res["fuzzy"].items():
        for i, r in enumerate(d["runs"]):
            tail = _pm(d["auc"]) if i == 0 else ""
            lines.append(f"{r['train_group'] + 1:>5} {key:>22} {res['max_error']:>8.4f} {r['threshold']:>8.4f} "
                         f"{r['sensitivity']:>7.4f} {r['specificity']:>7.4f} {r['ill_accepted']:>8.4f} {r['auc']:>8.4f} "
                         f"{r['spearman']:>7.3f}   {tail}")
    lines += ["", "Baselines (peer systems' gates at their own fixed thresholds; ROC AUC of the continuous score)"]
    lines.append(f"{'gate':>20} {'thr':>8} {'sens':>15} {'spec':>15} {'ill acc':>15} {'ROC AUC':>17} {'rho':>15}")
    for name, d in res["baselines"].items():
        r = d["runs"]
        sens = _ms([x["sensitivity"] for x in r])
        spec = _ms([x["specificity"] for x in r])
        lines.append(f"{name:>20} {r[0]['threshold']:>8.4g} {sens['mean']:>7.4f}±{sens['std']:.4f} "
                     f"{spec['mean']:>7.4f}±{spec['std']:.4f} {d['ill_accepted']['mean']:>7.4f}±{d['ill_accepted']['std']:.4f} "
                     f"{_pm(d['auc']):>17} {d['spearman']['mean']:>7.3f}±{d['spearman']['std']:.3f}")
    if res["fuzzy"]:
        best_base = max(res["baselines"].items(), key=lambda kv: kv[1]["auc"]["mean"])
        best_fuzzy = max(res["fuzzy"].items(), key=lambda kv: kv[1]["auc"]["mean"])
        lines.append("")
        named = [(label, ("&".join(inp), res["fuzzy"].get("&".join(inp))))
                 for label, inp in (("default", DEFAULT_INPUTS), ("paper's C&D", PAPER_INPUTS))]
        for label, (key, f) in (*named, ("best", best_fuzzy)):
            if f is None:
                continue
            lines.append(f"Summary ({label}) fuzzy {key}: ROC AUC {_pm(f['auc'])} (target >= 0.99), ill sets accepted "
                         f"{_pm(f['ill_accepted'])} (target <= 0.02), Spearman rho {_pm(f['spearman'])}")
        lines.append(f"Best baseline: {best_base[0]} ROC AUC {_pm(best_base[1]['auc'])}")
    return "\n".join(lines)


def plot_roc(res: dict[str, Any], path: Path) -> None:
    """ROC curves of the default fuzzy validator and the baselines on the test groups (PNG)."""
    import matplotlib  # optional dependency (plots only): imported when a plot is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 6.0))
    colours: dict[str, str] = {}
    for label, c in res["roc"].items():
        method, test = label.rsplit(" (", 1)
        colour = colours.setdefault(method, f"C{len(colours)}")
        fuzzy = method.startswith("fuzzy")
        ax.plot(c["fpr"], c["tpr"], "-" if test.startswith("test 1") else "--", color=colour, lw=1.6 if fuzzy else 1.0,
                label=label)
    ax.plot([0, 1], [0, 1], ":", color="grey", lw=0.8)
    ax.set_xlabel("ill-distributed sets accepted (1 - specificity)")
    ax.set_ylabel("good sets accepted (sensitivity)")
    ax.set_title(f"ROC on withheld sets, good = error < {res['max_error']:.2%}", fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_xlim(0, 0.4)
    ax.set_ylim(0.4, 1.005)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# -- subcommands -----------------------------------------------------------------------------------


def _check(args: argparse.Namespace, outputs: list[tuple[str, Path | None]]) -> None:
    """The seed (numpy refuses a negative one with a traceback) and the paths (``check_paths``), before any work."""
    if args.seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {args.seed}")
    corpus = getattr(args, "corpus", None)
    check_paths([("the --corpus", None if corpus is None else Path(corpus))],
                [(label, None if path is None else Path(path)) for label, path in outputs])


def _corpus_from(args: argparse.Namespace) -> Corpus:
    if getattr(args, "corpus", None):
        return Corpus.load(args.corpus)
    return build_corpus(args.n_sets, args.seed, progress=True)


def _run_build(args: argparse.Namespace) -> int:
    out = Path(args.out)
    _check(args, [("--out", out if out.suffix == ".npz" else out.with_name(out.name + ".npz"))])  # what Corpus.save writes
    c = build_corpus(args.n_sets, args.seed, progress=True)
    path = c.save(args.out)
    good = c.good(args.max_error)
    print(f"wrote {path}: {len(c)} sets, {int(good.sum())} good (error < {args.max_error:.2%}), "
          f"{c.meta.get('n_failed', 0)} failed fits")
    return 0


def _run_train(args: argparse.Namespace) -> int:
    _check(args, [("--out", args.out)])
    c = _corpus_from(args)
    inputs = tuple(args.inputs.split(","))
    v = train_fuzzy(c, inputs, n_mf=args.n_mf, repeats=args.repeats, max_error=args.max_error, max_fpr=args.max_fpr,
                    seed=args.seed, consequents=args.consequents)
    v.metadata.update({"corpus": c.meta, "command": " ".join(sys.argv)})
    v.save(args.out)
    pred = v.predict(c.matrix(inputs))
    print(f"wrote {args.out}: inputs {inputs}, threshold {v.threshold:.4g}, training ROC AUC "
          f"{roc_auc(-pred, c.good(args.max_error)):.4f} on {len(c)} sets")
    return 0


def _run_evaluate(args: argparse.Namespace) -> int:
    _check(args, [("--json", args.json), ("--plot", args.plot)])
    c = _corpus_from(args)
    pairs = None
    if args.pairs:
        pairs = tuple(tuple(p.split(",")) for p in args.pairs)
    res = evaluate(c, max_error=args.max_error, max_fpr=args.max_fpr, pairs=pairs, n_mf=args.n_mf,
                   repeats=args.repeats, seed=args.seed, progress=True, consequents=args.consequents)
    print(format_tables(res))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")
    if args.plot:
        plot_roc(res, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _common(p: argparse.ArgumentParser, *, corpus_in: bool) -> None:
    if corpus_in:
        p.add_argument("--corpus", help="corpus .npz from build-corpus (default: build one with --n-sets/--seed)")
    p.add_argument("--n-sets", type=int, default=2000, help="sets to simulate (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="corpus and training seed (default 0)")
    p.add_argument("--max-error", type=float, default=DEFAULT_MAX_ERROR,
                   help=f"calibration error below which a set is good (default {DEFAULT_MAX_ERROR})")


def _fuzzy_opts(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n-mf", type=int, default=10, help="triangular MFs per input (default 10)")
    p.add_argument("--repeats", type=int, default=10, help="passes over the training sets (default 10)")
    p.add_argument("--max-fpr", type=float, default=DEFAULT_MAX_FPR,
                   help=f"cap on ill training sets accepted when tuning the threshold (default {DEFAULT_MAX_FPR})")
    p.add_argument("--consequents", choices=("paper", "lsq"), default=DEFAULT_CONSEQUENTS,
                   help="'paper': consequents of the online Eq. 21 rule only; 'lsq': then re-solved by least "
                        f"squares over the trained partition (default {DEFAULT_CONSEQUENTS})")


def register(subparsers: Any) -> None:
    """Add ``build-corpus``, ``train-validator`` and ``evaluate-validator`` to the ``margcal`` parser."""
    p = subparsers.add_parser("build-corpus", help="simulate labelled calibration sets (.npz)")
    _common(p, corpus_in=False)
    p.add_argument("--out", required=True, help="output .npz")
    p.set_defaults(func=_run_build)

    p = subparsers.add_parser("train-validator", help="train the fuzzy validator on a corpus, write JSON")
    _common(p, corpus_in=True)
    _fuzzy_opts(p)
    p.add_argument("--inputs", default=",".join(DEFAULT_INPUTS), help=f"comma-separated features from {FEATURES}")
    p.add_argument("--out", required=True, help="output validator .json")
    p.set_defaults(func=_run_train)

    p = subparsers.add_parser("evaluate-validator",
                              help="Olivares Tables 1-3 with the train/test swap, baselines, ROC plot")
    _common(p, corpus_in=True)
    _fuzzy_opts(p)
    p.add_argument("--pairs", nargs="*", help="fuzzy input sets, e.g. c_norm,d_norm C,D (default: paper pairs + normalised)")
    p.add_argument("--json", help="write all figures as JSON")
    p.add_argument("--plot", type=plot_file, metavar="FILE.png", help="write the ROC plot (PNG, or another image format)")
    p.set_defaults(func=_run_evaluate)
