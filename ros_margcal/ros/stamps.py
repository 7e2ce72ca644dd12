"""Which time a sample gets: the message's header stamp or the time it was received (no rclpy).

Some drivers publish zero or constant header stamps; the calibrator drops every sample whose time
does not increase (``repeated_stamp`` / ``backwards_stamp``), so such a driver would never be
calibrated. ``StampSource`` chooses per sample, for the node's ``stamp_source`` parameter:

- ``"header"``: always the header stamp (a driver with good stamps; replay-like behaviour);
- ``"receive"``: always the receive time (the node clock when the callback runs);
- ``"auto"`` (default): the header stamp while it is usable; the first time it is zero or does not
  increase, the source switches to the receive time for good and says so once (``warning``), so a
  driver with broken stamps is calibrated on receive times and one with good stamps keeps them.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["STAMP_SOURCES", "StampSource"]

STAMP_SOURCES = ("auto", "header", "receive")


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

    @property
    def using(self) -> str:
        """The source in use now: ``"header"`` or ``"receive"``."""
        return "receive" if self.mode == "receive" or self.fell_back else "header"

    def choose(self, header_t: float, receive_t: float | Callable[[], float]) -> float:
        """The time of a sample with header stamp ``header_t`` received at ``receive_t`` (seconds, or a
        function giving it, called only when the receive time is used).

        In ``auto`` mode the first unusable header stamp (zero, repeated or going backwards) switches to
        the receive time for good and sets ``warning`` once (the caller logs it and clears it).
        """
        if self.mode == "header":
            return header_t
        if self.mode == "receive" or self.fell_back:
            return receive_t() if callable(receive_t) else receive_t
        last = self._last_header
        if header_t <= 0.0 or (last is not None and header_t <= last):
            self.fell_back = True
            why = ("zero" if header_t == 0.0 else "negative (a stamp beyond 2038 wraps int32 sec)" if header_t < 0.0
                   else "repeated" if header_t == last else "going backwards")
            after = "" if last is None else f" after {last:.9f} s"
            self.warning = (f"{self.stream}: header stamps are {why} ({header_t:.9f} s{after}); "
                            "using the receive time from now on (set stamp_source to 'header' or 'receive' to choose)")
            return receive_t() if callable(receive_t) else receive_t
        self._last_header = header_t
        return header_t

    def pop_warning(self) -> str | None:
        """The pending one-time warning (then None)."""
        w, self.warning = self.warning, None
        return w
