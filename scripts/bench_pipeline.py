"""Benchmark of the streaming pipeline (``margcal bench pipeline``); pass ``--quick`` for a short run."""
import sys

from ros_margcal.bench.pipeline import main

sys.exit(main(sys.argv[1:]))
