"""StampSource: header stamps, receive times, and the one-time fall-back of ``auto`` (no rclpy)."""

from __future__ import annotations

import itertools

import pytest

from ros_margcal.ros.stamps import FALLBACK_BAD, RECEIVE_CATCH_UP_S, StampSource
from ros_margcal.stream.calibrator import SensorCalibrator


def test_header_and_receive_modes_never_switch() -> None:
    hdr, rcv = StampSource("header"), StampSource("receive")
    for h, r in ((0.0, 5.0), (0.0, 5.1), (3.0, 5.2)):
        assert hdr.choose(h, r) == h
        assert rcv.choose(h, r) == r
    assert hdr.using == "header" and rcv.using == "receive"
    assert hdr.pop_warning() is None and rcv.pop_warning() is None


def test_auto_keeps_good_header_stamps() -> None:
    src = StampSource("auto", "imu/mag")
    assert [src.choose(1.0 + 0.01 * k, 100.0 + k) for k in range(5)] == [1.0 + 0.01 * k for k in range(5)]
    assert src.using == "header" and src.pop_warning() is None


@pytest.mark.parametrize(("stamps", "why", "switch"), [([0.0] * 5, "zero", 1), ([2.0] * 6, "repeated", 3),
                                                       ([2.0, 1.5, 1.4, 3.0, 2.5, 4.0], "backwards", 2)])
def test_auto_falls_back_to_receive_time_once(stamps: list[float], why: str, switch: int) -> None:
    """The second unusable stamp of the last 20 switches to the receive time, for good, with one warning."""
    src = StampSource("auto", "imu/mag")
    out = [src.choose(h, 10.0 + k) for k, h in enumerate(stamps)]
    assert out[:switch] == stamps[:switch]
    assert out[switch:] == [10.0 + k for k in range(switch, len(stamps))]
    assert src.using == "receive"
    w = src.pop_warning()
    assert w is not None and "imu/mag" in w and why in w and "receive time" in w and "2 of the last" in w
    src.choose(50.0, 20.0)  # a good stamp later does not switch back, and there is no second warning
    assert src.using == "receive" and src.pop_warning() is None


def test_auto_passes_a_stray_stamp_on() -> None:
    """One zero stamp, a clock reset and a repeated stamp in a good stream keep the header stamps: the calibrator
    drops the stray ones and counts them (the node fuzz: one zero stamp moved a 100 Hz stream to receive times for
    good, whose DDS bunches were then dropped as bursts)."""
    src = StampSource("auto", "imu/mag")
    stamps = [1.0 + 0.01 * k for k in range(200)]
    stamps[30] = 0.0  # a zero stamp
    stamps[90] = stamps[89]  # a repeated one
    stamps[150:] = [0.5 + 0.01 * k for k in range(50)]  # the clock restarts
    cal = SensorCalibrator("mag")
    for k, h in enumerate(stamps):
        t = src.choose(h, 1000.0 + k)
        assert t == h
        cal.push(t, (20e-6 + 1e-7 * k, 5e-6, -30e-6))
    assert src.using == "header" and src.pop_warning() is None
    assert cal.dropped["backwards_stamp"] + cal.dropped["repeated_stamp"] >= 2


def test_auto_keeps_header_stamps_of_messages_published_twice() -> None:
    """A driver that publishes every message twice repeats each stamp once: the header stamps are kept and the
    calibrator drops the copies as repeated (on receive times, spaced out, the copies were taken as samples)."""
    src = StampSource("auto", "imu/mag")
    cal = SensorCalibrator("mag")
    for k in range(400):
        h = 1.0 + 0.01 * (k // 2)
        assert src.choose(h, 1000.0 + 1e-4 * k) == h
        cal.push(h, (20e-6 + 1e-7 * (k // 2), 5e-6, -30e-6))
    assert src.using == "header" and cal.dropped["repeated_stamp"] == 200


def test_receive_times_in_bunches_are_spaced_not_dropped() -> None:
    """DDS hands 100 Hz messages over five at a time, 20 us apart: every one kept, times in order and at most
    ``RECEIVE_CATCH_UP_S`` late; a real burst far above the rate is not spread out (the calibrator drops it)."""
    cal = SensorCalibrator("mag")
    src = StampSource("receive")
    step = 1.01 * cal.config.min_period_s
    rx = [0.05 * (k // 5) + 2e-5 * (k % 5) for k in range(1000)]
    ts = [src.choose(0.0, r, step) for r in rx]
    assert all(b - a >= step * (1 - 1e-9) for a, b in itertools.pairwise(ts))
    assert max(t - r for t, r in zip(ts, rx, strict=True)) <= RECEIVE_CATCH_UP_S
    for k, t in enumerate(ts):
        cal.push(t, (20e-6 + 1e-8 * k, 5e-6, -30e-6))
    assert cal.dropped["burst"] == 0 and cal.passed + cal.dropped["spike"] == 1000
    burst = StampSource("receive")
    out = [burst.choose(0.0, 1e-6 * k, step) for k in range(2000)]  # 2000 messages in 2 ms
    assert out[-1] <= 2e-3 + RECEIVE_CATCH_UP_S + step


def test_constant_stamps_are_all_dropped_unless_auto() -> None:
    """The failure the parameter exists for: a constant stamp drops every sample but the first on header time
    (receive times are the node clock, 1.7e9 s of ROS time, after the bad stamp)."""
    header_only, auto = SensorCalibrator("mag"), SensorCalibrator("mag")
    hdr, src = StampSource("header"), StampSource("auto")
    for k in range(100):
        v = (20e-6 + 1e-7 * k, 5e-6, -30e-6)
        header_only.push(hdr.choose(7.0, 0.02 * k + 1.7e9), v)
        auto.push(src.choose(7.0, 0.02 * k + 1.7e9), v)
    assert header_only.dropped["repeated_stamp"] == 99
    # auto switches to the receive time once: the intake sees one jump to a new time base (stream/intake.py)
    # and spends at most new_time_base_after - 1 samples confirming it, instead of dropping all but one
    # (after the stamps that repeat the one before and the next switches: stamps.FALLBACK_BAD)
    assert auto.dropped["repeated_stamp"] == FALLBACK_BAD
    assert auto.status().time_base_resets == 1
    assert auto.passed >= 100 - FALLBACK_BAD - (auto.config.new_time_base_after - 1)



def test_receive_time_is_asked_for_only_when_used() -> None:
    calls = []

    def now() -> float:
        calls.append(1)
        return 100.0 + len(calls)

    src = StampSource("auto")
    assert src.choose(1.0, now) == 1.0 and src.choose(2.0, now) == 2.0 and not calls
    assert [src.choose(0.0, now) for _ in range(2)] == [0.0, 101.0] and len(calls) == 1
    assert StampSource("header").choose(0.0, now) == 0.0 and len(calls) == 1


def test_unknown_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="stamp_source"):
        StampSource("gps")
