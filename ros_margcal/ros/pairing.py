"""Which Imu angular rate goes with each magnetometer sample, whatever order the two topics arrive in (no rclpy).

The gyro-aided fit (``model/fitting_gyro.py``) needs the angular rate at each magnetometer sample, in the
magnetometer's frame. Imu and MagneticField arrive on two topics, and an executor may serve either first:
pairing each magnetometer sample with the *latest* rate seen would give a sample the rate of the previous
Imu message, or none, depending on callback order. ``RatePairing`` holds a magnetometer sample back until
the rate nearest to its stamp is known: an Imu message of the same ``frame_id`` stamped at or after it has
arrived, or ``hold_s`` of arrival time has passed (an IMU slower than the magnetometer, one that
stopped, one in another frame), then gives it the rate of the Imu message nearest in stamp within
``window_s``, else none. A magnetometer whose ``frame_id`` no Imu message carries takes the rates of the one
Imu frame when there is exactly one (a robot's ``mag_link`` beside its ``imu_link``: the gyro-aided fit checks
which axis order and rotation the rates are in, ``model/mounting.py``); with two or more it takes none.
Magnetometer samples leave in the order they came. Holding delays only the
calibrator's input (by at most ``hold_s``), never the calibrated message, which the node publishes at once.
"""

from __future__ import annotations

from collections import deque
from typing import Any

__all__ = ["RatePairing"]


class RatePairing:
    """Pairs magnetometer samples with the nearest Imu rate of their frame, or of the only Imu frame (see the module
    docstring).

    Args:
        window_s: the largest stamp difference of a pair, s (``stream.config.GYRO_PAIR_S``).
        hold_s: the longest a magnetometer sample waits for a later rate, s of arrival time.
        history: rates kept per frame.
    """

    def __init__(self, window_s: float, hold_s: float = 0.25, history: int = 256) -> None:
        self.window_s = float(window_s)
        self.hold_s = float(hold_s)
        self._rates: dict[str, deque[tuple[float, Any]]] = {}
        self._history = int(history)
        self._held: deque[tuple[float, str, Any, float]] = deque()

    def __len__(self) -> int:
        """Magnetometer samples held back."""
        return len(self._held)

    def add_rate(self, t: float, frame: str, gyro: Any, arrival: float) -> list[tuple[float, Any, Any]]:
        """Record the rate of an Imu message (stamp ``t``); the magnetometer samples it releases."""
        rates = self._rates.get(frame)
        if rates is None:
            rates = self._rates[frame] = deque(maxlen=self._history)
        rates.append((t, gyro))
        return self.release(arrival)

    def add_mag(self, t: float, frame: str, xyz: Any, arrival: float) -> list[tuple[float, Any, Any]]:
        """Hold a magnetometer sample until its rate is known; the samples released, ``(t, xyz, gyro or None)``."""
        self._held.append((t, frame, xyz, arrival))
        return self.release(arrival)

    def release(self, now: float, everything: bool = False) -> list[tuple[float, Any, Any]]:
        """The held samples whose rate is known or whose wait is over at arrival time ``now``, in order."""
        out = []
        held = self._held
        while held:
            t, frame, xyz, arrival = held[0]
            rates = self._rates_for(frame)
            if not everything and now - arrival <= self.hold_s and (rates is None or rates[-1][0] < t):
                break  # a rate stamped at or after t may still come
            held.popleft()
            out.append((t, xyz, self._nearest(rates, t)))
        return out

    def _rates_for(self, frame: str) -> deque[tuple[float, Any]] | None:
        """The rates of ``frame``, else of the only Imu frame seen (module docstring), else None."""
        rates = self._rates.get(frame)
        if rates is None and len(self._rates) == 1:
            rates = next(iter(self._rates.values()))
        return rates

    def _nearest(self, rates: deque[tuple[float, Any]] | None, t: float) -> Any:
        best, best_dt = None, self.window_s
        for tr, gyro in reversed(rates or ()):
            dt = abs(tr - t)
            if dt <= best_dt:
                best, best_dt = gyro, dt
            elif tr < t - self.window_s:
                break
        return best

    def clear(self) -> None:
        """Forget rates and held samples (a reset)."""
        self._rates.clear()
        self._held.clear()
