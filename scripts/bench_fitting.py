"""Fitting benchmark (Gietzelt Table 4, Cramér-Rao efficiency, speed); see ros_margcal.bench.fitting."""

import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # "one core": set before numpy loads

from ros_margcal.bench.fitting import main

sys.exit(main(sys.argv[1:]))
