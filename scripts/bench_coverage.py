"""Coverage benchmark (``margcal bench coverage``); pass ``--quick`` for a short run."""
import sys

from ros_margcal.bench.coverage import main

sys.exit(main(sys.argv[1:]))
