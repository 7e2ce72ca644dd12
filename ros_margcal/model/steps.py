"""Computations in steps: a generator that yields between its parts and returns its result.

A stream runs a long fit one step a sample (``stream.evaluation``, **Fits in steps**) so that no single sample pays for
all of it; a batch caller runs it to the end (``drained``). The steps never change the result: the same code, paused.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import TypeVar

__all__ = ["Steps", "drained"]

T = TypeVar("T")

Steps = Generator[None, None, T]
"""A computation in steps: each ``next`` runs one, ``StopIteration.value`` is the result."""


def drained(steps: Steps[T]) -> T:
    """Run ``steps`` to the end and return its result."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]
