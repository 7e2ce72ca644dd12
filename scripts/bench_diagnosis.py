"""Diagnosis benchmark (withheld effects, real hold-out, speed); see ros_margcal.bench.diagnosis."""

import sys

from ros_margcal.bench.diagnosis import main

sys.exit(main(sys.argv[1:]))
