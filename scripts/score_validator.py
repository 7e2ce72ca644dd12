#!/usr/bin/env python3
"""Score a trained validator (default: the shipped one) on corpora it was not trained on.

    margcal build-corpus --n-sets 4000 --seed 7 --out c7.npz
    python scripts/score_validator.py c7.npz [c8.npz ...] [--validator FILE]

Prints, per corpus, the ROC AUC of the predicted error, the good and ill sets accepted at the
validator's own threshold, and the Spearman rank correlation of predicted and true error over the
sets whose fit succeeded (the node shows the number, not only the verdict).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.stats import spearmanr

from ros_margcal.training.corpus import FAILED_ERROR, Corpus
from ros_margcal.validation.roc import roc_auc
from ros_margcal.validation.shipped import load_default_validator, load_validator


def main(argv: list[str] | None = None) -> int:
    """Score the validator on each corpus given."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corpora", nargs="+", help="corpus .npz files from margcal build-corpus")
    ap.add_argument("--validator", help="validator JSON (default: the shipped one)")
    args = ap.parse_args(argv)
    v = load_validator(args.validator) if args.validator else load_default_validator()
    print(f"validator inputs {'&'.join(v.inputs)}, threshold {v.threshold:.4g}, trained on {v.metadata.get('corpus')}")
    rows = []
    for path in args.corpora:
        c = Corpus.load(path)
        good = c.good(v.max_error)
        pred = v.predict(c.matrix(v.inputs))
        acc = pred <= v.threshold
        fitted = c.error < FAILED_ERROR
        row = (roc_auc(-pred, good), float(acc[~good].mean()), float(acc[good].mean()),
               float(spearmanr(pred[fitted], c.error[fitted])[0]))
        rows.append(row)
        print(f"{path}: {len(c)} sets, AUC {row[0]:.4f}, ill accepted {row[1]:.2%}, good accepted {row[2]:.1%}, "
              f"Spearman {row[3]:.3f}")
    m = np.mean(rows, axis=0)
    print(f"mean: AUC {m[0]:.4f} (target >= 0.99), ill accepted {m[1]:.2%} (target <= 2 %), good accepted {m[2]:.1%}, "
          f"Spearman {m[3]:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
