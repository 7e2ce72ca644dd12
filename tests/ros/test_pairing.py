"""RatePairing: each magnetometer sample gets the Imu rate nearest in stamp, whatever order the topics arrive in."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.ros.pairing import RatePairing

WINDOW = 0.02


def _run(events: list[tuple[str, float, str, float]]) -> list[tuple[float, float | None]]:
    """Feed (kind, stamp, frame, arrival) events; (mag stamp, paired rate's stamp or None) in release order."""
    p = RatePairing(WINDOW, hold_s=0.25)
    out = []
    for kind, t, frame, arrival in events:
        got = p.add_rate(t, frame, t, arrival) if kind == "imu" else p.add_mag(t, frame, None, arrival)
        out += [(tm, g) for tm, _, g in got]
    out += [(tm, g) for tm, _, g in p.release(1e9)]
    return out


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.005, 0.01, 0.02]), st.sampled_from([0.01, 0.02, 0.05]))
def test_pairing_does_not_depend_on_arrival_order(seed: int, imu_dt: float, mag_dt: float) -> None:
    """Any interleaving of the two topics (each in stamp order, arriving within 0.1 s of its stamp) gives
    every magnetometer sample, in order, the rate of the Imu stamp nearest to it within the window."""
    rng = np.random.default_rng(seed)
    imu_t = 10.0 + imu_dt * np.arange(int(2.0 / imu_dt))
    mag_t = 10.003 + mag_dt * np.arange(int(2.0 / mag_dt))
    delay = lambda n: np.sort(rng.uniform(0.0, 0.1, n))  # noqa: E731 - arrival delays, increasing within a topic
    imu_arr, mag_arr = imu_t + delay(len(imu_t)) * 0.1, mag_t + delay(len(mag_t)) * 0.1
    events = sorted([("imu", t, "imu_link", a) for t, a in zip(imu_t, imu_arr, strict=True)]
                    + [("mag", t, "imu_link", a) for t, a in zip(mag_t, mag_arr, strict=True)], key=lambda e: e[3])
    out = _run(events)
    assert [t for t, _ in out] == list(mag_t)
    for t, g in out:
        k = int(np.argmin(np.abs(imu_t - t)))
        assert g == imu_t[k] if abs(imu_t[k] - t) <= WINDOW else g is None


def test_mag_first_or_imu_first_alike() -> None:
    """The executor serving the magnetometer before or after its Imu message gives the same pairs."""
    imu_first, mag_first = [], []
    for k in range(20):
        t, a = 100.0 + 0.02 * k, 0.02 * k
        imu_first += [("imu", t, "imu_link", a), ("mag", t + 0.005, "imu_link", a + 0.001)]
        mag_first += [("mag", t + 0.005, "imu_link", a), ("imu", t, "imu_link", a + 0.001)]
    assert _run(imu_first) == _run(mag_first)
    assert all(g is not None and abs(g - t) <= 0.005 + 1e-9 for t, g in _run(mag_first))


def test_other_frame_and_a_silent_imu_wait_at_most_hold_s() -> None:
    """A magnetometer in another frame than the two Imu frames, or after the IMU stopped, waits at most ``hold_s``
    of arrival time, then leaves with the nearest rate within the window, or none; samples leave in order."""
    p = RatePairing(WINDOW, hold_s=0.25)
    assert p.add_rate(1.0, "imu_link", "g", arrival=0.0) == []
    assert p.add_rate(1.0, "imu2_link", "h", arrival=0.0) == []
    assert p.add_mag(1.005, "mag_link", "v", arrival=0.0) == []
    assert p.add_mag(1.010, "imu_link", "w", arrival=0.01) == []  # a later rate may still come
    assert len(p) == 2
    assert p.release(0.2) == []
    assert p.release(0.3) == [(1.005, "v", None), (1.010, "w", "g")]  # the wait is over; two Imu frames: none
    assert p.add_mag(5.0, "imu_link", "x", arrival=0.3) == []
    assert p.release(0.6) == [(5.0, "x", None)]  # the IMU is silent: no rate within the window


def test_a_magnetometer_in_its_own_frame_takes_the_only_imu_frame_rates() -> None:
    """mag_link beside one imu_link: the Imu's rates (the fit checks their axes), not none."""
    p = RatePairing(WINDOW, hold_s=0.25)
    assert p.add_mag(1.005, "mag_link", "v", arrival=0.0) == []
    assert p.add_rate(1.0, "imu_link", "g", arrival=0.001) == []
    assert p.add_rate(1.01, "imu_link", "h", arrival=0.002) == [(1.005, "v", "g")]
