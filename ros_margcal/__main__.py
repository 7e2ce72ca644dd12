"""``python -m ros_margcal`` runs the ``margcal`` command."""

import sys

from .cli import main

sys.exit(main())
