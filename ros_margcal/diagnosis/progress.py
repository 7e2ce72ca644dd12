"""Progress of a whole ``margcal diagnose`` command: one bar across every step, and its wall time.

The steps are counted up front (``command_steps``: the twin, the baseline's spread, each effect of the
ranking, the decision; the validator's retraining; the withheld part), so the bar reaches its end when the
command does. ``CommandProgress`` is the callback ``diagnose``, ``validator_downstream`` and
``diagnose_holdout`` take (``progress(done, total, name)``); it draws a tqdm bar on stderr when stderr is a
terminal (nothing otherwise) and keeps the wall time since it was made (``seconds``).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from tqdm import tqdm

from .ranking import applicable_effects

__all__ = ["CommandProgress", "command_steps", "diagnosis_steps"]

TWIN_STEPS = 3
"""Steps of one diagnosis besides its effects: the twin, the baseline's spread, the decision."""
HOLDOUT_STEPS = 3
"""Steps of the withheld-part check that fits the named cause: the first part's twin, its fit, the rest."""


def diagnosis_steps(sensor: str) -> int:
    """Progress steps of one ``diagnose`` of a ``sensor`` recording."""
    return TWIN_STEPS + len(applicable_effects(sensor)[0])


def command_steps(sensor: str, *, downstream: bool, holdout: bool) -> int:
    """Progress steps of a whole ``margcal diagnose``: the diagnosis, the validator's retraining (one step),
    the withheld part (``HOLDOUT_STEPS``)."""
    return diagnosis_steps(sensor) + int(downstream) + (HOLDOUT_STEPS if holdout else 0)


class CommandProgress:
    """One progress bar across a command's steps (stderr, terminals only) and the command's wall time."""

    def __init__(self, total: int, *, desc: str = "diagnose", file: Any = None, start: float | None = None) -> None:
        self.start = time.monotonic() if start is None else start
        self.bar = tqdm(total=total, desc=desc, unit=" step", file=file or sys.stderr, disable=None, leave=False)
        self.done = 0

    def __call__(self, done: int, total: int, name: str) -> None:
        """One step done (``done`` and ``total`` of the caller's own part are not needed: the bar counts)."""
        self.done += 1
        self.bar.set_postfix_str(name, refresh=False)
        self.bar.update(1)

    @property
    def seconds(self) -> float:
        """Wall time since the command started."""
        return time.monotonic() - self.start

    def close(self) -> None:
        """Remove the bar (the summary follows on stdout)."""
        self.bar.close()
