"""Which time a sample gets: the message's header stamp or the time it was received (no rclpy).

Some drivers publish zero or constant header stamps; the calibrator drops every sample whose time
does not increase (``repeated_stamp`` / ``backwards_stamp``), so such a driver would never be
calibrated. ``StampSource`` chooses per sample, for the node's ``stamp_source`` parameter:

- ``"header"``: always the header stamp (a driver with good stamps; replay-like behaviour);
- ``"receive"``: always the receive time (the node clock when the callback runs);
- ``"auto"`` (default): the header stamp while it is usable; when ``FALLBACK_BAD`` of the last
  ``FALLBACK_WINDOW`` stamps are zero, go backwards or repeat the two before, the source switches to the
  receive time for good and says so once (``warning``), so a driver with broken stamps is calibrated on
  receive times and one with good stamps keeps them: a single stray stamp (one zero, a clock reset) is
  passed on, and the calibrator drops it and counts it (``backwards_stamp``), instead of moving the stream
  to receive times; a message published twice (its stamp repeated once) is dropped as ``repeated_stamp``.

Receive times are spaced at least ``min_step`` apart (``RECEIVE_CATCH_UP_S`` at most behind): DDS hands
messages over in bunches, whose receive times, microseconds apart, the calibrator dropped as bursts (197
of 3000 messages at 100 Hz); a stamp moved later by a few ms is harmless, a dropped sample is not.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

__all__ = ["STAMP_SOURCES", "StampSource"]

STAMP_SOURCES = ("auto", "header", "receive")
FALLBACK_WINDOW = 20
"""``auto``: the last header stamps whose unusable ones are counted."""
FALLBACK_BAD = 2
"""``auto``: unusable stamps among the last ``FALLBACK_WINDOW`` that switch to the receive time."""
RECEIVE_CATCH_UP_S = 0.05
"""Receive times are moved at most this much later to keep ``min_step`` apart (beyond: a real burst)."""


class StampSource:
    """Chooses the time of each sample of one stream (see the module docstring).

    Args:
        mode: ``"auto"``, ``"header"`` or ``"receive"``.
        stream: a name for the warning (e.g. the topic or the sensor).
    """

    def __init__(self, mode: str = "auto", stream: str = "") -> None:
        if mode not in STAMP_SOURCES:
            msg = f"stamp_source must be one of {STAMP_SOURCES}, got {mode!r}"
            raise ValueError(msg)
        self.mode = mode
        self.stream = stream
        self.fell_back = False
        self.warning: str | None = None
        self._last_header: float | None = None
        self._before_last: float | None = None
        self._bad: deque[bool] = deque(maxlen=FALLBACK_WINDOW)
        self._last_receive = -math.inf

    @property
    def using(self) -> str:
        """The source in use now: ``"header"`` or ``"receive"``."""
        return "receive" if self.mode == "receive" or self.fell_back else "header"

    def choose(self, header_t: float, receive_t: float | Callable[[], float], min_step: float = 0.0) -> float:
        """The time of a sample with header stamp ``header_t`` received at ``receive_t`` (seconds, or a
        function giving it, called only when the receive time is used); receive times at least ``min_step``
        after the last one given (the calibrator's ``min_period_s``: see the module docstring).

        In ``auto`` mode ``FALLBACK_BAD`` unusable header stamps (zero, going backwards, or equal to the two before)
        among the last ``FALLBACK_WINDOW`` switch to the receive time for good and set ``warning`` once (the caller logs
        it and clears it); fewer are passed on as they are.
        """
        if self.mode == "header":
            return header_t
        if self.mode == "receive" or self.fell_back:
            return self._receive(receive_t, min_step)
        last, before = self._last_header, self._before_last
        bad = header_t <= 0.0 or (last is not None and (header_t < last or header_t == last == before))
        self._bad.append(bad)
        self._last_header, self._before_last = header_t, last
        if bad and sum(self._bad) >= FALLBACK_BAD:
            self.fell_back = True
            why = ("zero" if header_t == 0.0 else "negative (a stamp beyond 2038 wraps int32 sec)" if header_t < 0.0
                   else "repeated" if header_t == last else "going backwards")
            after = "" if last is None else f" after {last:.9f} s"
            self.warning = (f"{self.stream}: {sum(self._bad)} of the last {len(self._bad)} header stamps are zero, going "
                            f"backwards or repeated, the last {why} ({header_t:.9f} s{after}); using the receive time from "
                            "now on (set stamp_source to 'header' or 'receive' to choose)")
            return self._receive(receive_t, min_step)
        return header_t

    def _receive(self, receive_t: float | Callable[[], float], min_step: float) -> float:
        """The receive time, moved to ``min_step`` after the last one when it is at most ``RECEIVE_CATCH_UP_S`` behind."""
        t = receive_t() if callable(receive_t) else receive_t
        t = max(t, self._last_receive + min_step) if t > self._last_receive + min_step - RECEIVE_CATCH_UP_S else t
        self._last_receive = t
        return t

    def pop_warning(self) -> str | None:
        """The pending one-time warning (then None)."""
        w, self.warning = self.warning, None
        return w
