"""StampSource: header stamps, receive times, and the one-time fall-back of ``auto`` (no rclpy)."""

from __future__ import annotations

import pytest

from ros_margcal.ros.stamps import StampSource
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


@pytest.mark.parametrize(("stamps", "why"), [([0.0, 0.0, 0.0], "zero"), ([2.0, 2.0, 2.0], "repeated"),
                                             ([2.0, 1.5, 3.0], "backwards")])
def test_auto_falls_back_to_receive_time_once(stamps: list[float], why: str) -> None:
    src = StampSource("auto", "imu/mag")
    out = [src.choose(h, 10.0 + k) for k, h in enumerate(stamps)]
    first_bad = 0 if why == "zero" else 1
    assert out[:first_bad] == stamps[:first_bad]
    assert out[first_bad:] == [10.0 + k for k in range(first_bad, len(stamps))]
    assert src.using == "receive"
    w = src.pop_warning()
    assert w is not None and "imu/mag" in w and why in w and "receive time" in w
    src.choose(50.0, 20.0)  # a good stamp later does not switch back, and there is no second warning
    assert src.using == "receive" and src.pop_warning() is None


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
    assert auto.dropped["repeated_stamp"] == 0
    assert auto.status().time_base_resets == 1
    assert auto.passed >= 100 - (auto.config.new_time_base_after - 1)


def test_receive_time_is_asked_for_only_when_used() -> None:
    calls = []

    def now() -> float:
        calls.append(1)
        return 100.0 + len(calls)

    src = StampSource("auto")
    assert src.choose(1.0, now) == 1.0 and src.choose(2.0, now) == 2.0 and not calls
    assert src.choose(2.0, now) == 101.0 and len(calls) == 1
    assert StampSource("header").choose(0.0, now) == 0.0 and len(calls) == 1


def test_unknown_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="stamp_source"):
        StampSource("gps")
