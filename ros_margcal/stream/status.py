"""The values the streaming calibrator reports: state, events, and the status ``/calib/status`` shows.

``Level`` mirrors diagnostic_msgs/DiagnosticStatus levels as an ``IntEnum``; the node alone turns
it into the one-byte ``bytes`` rclpy wants (rosbags takes the int).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import Any

from ..model.calibration import Calibration

__all__ = ["Event", "EventKind", "Level", "State", "Status", "pct"]


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels (ints here; bytes only inside the node)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class State(str, Enum):
    """Where a sensor's calibration stands."""

    COLLECTING = "collecting"
    READY = "ready"
    CALIBRATED = "calibrated"
    REJECTED = "rejected"


class EventKind(str, Enum):
    """What ``push`` and ``refit`` report."""

    STATE = "state"            # the state changed
    CALIBRATED = "calibrated"  # a new calibration passed the guard rails and is now current
    REJECTED = "rejected"      # a fit was refused; ``message`` says why
    CHANGED = "changed"        # the current calibration no longer fits new samples
    TIME_BASE = "time_base"    # the stamps restarted (a bag loop, a driver restart): a new time base


@dataclass(frozen=True)
class Event:
    """One thing that happened, at message time ``t``."""

    kind: EventKind
    t: float
    sensor: str
    message: str
    calibration: Calibration | None = None


@dataclass(frozen=True)
class Status:
    """Everything ``/calib/status`` shows for one sensor."""

    sensor: str
    level: Level
    state: State
    message: str
    t: float
    samples_seen: int
    samples_kept: int
    samples_rejected: int
    dropped: dict[str, int] = field(default_factory=dict)
    buffer_size: int = 0
    coverage: float = 0.0
    indicators: dict[str, float] = field(default_factory=dict)
    predicted_error: float | None = None
    error_threshold: float | None = None
    residual: float | None = None
    offset: tuple[float, ...] | None = None
    matrix: tuple[float, ...] | None = None
    norm: float | None = None
    age: float | None = None
    fits_accepted: int = 0
    fits_rejected: int = 0
    last_rejection: str = ""
    changes_detected: int = 0
    samples_passed: int = 0  # samples_seen == samples_passed + samples_rejected
    time_base_resets: int = 0
    gyro_ignored: int = 0
    partial: bool = False  # the calibration is partial: some parameters come from the prior
    updated_parameters: tuple[str, ...] = ()  # partial: the parameters the data determined
    prior_parameters: tuple[str, ...] = ()  # partial: the parameters kept from the prior
    heading_p95_level_deg: float | None = None  # magnetometer: predicted heading error p95, level, degrees
    heading_p95_tilt30_deg: float | None = None  # ... with roll and pitch up to 30 deg
    heading_typical_level_deg: float | None = None  # magnetometer: the heading p95 it most likely measures (median), level
    heading_typical_tilt30_deg: float | None = None  # ... with roll and pitch up to 30 deg
    heading_inclination_deg: float | None = None  # the field inclination they hold at, deg (a position's, a ring's, or 60)
    tilt_seen_deg: float | None = None  # partial: the tilt range of the data it was fitted on, degrees
    gyro_explained: float | None = None  # magnetometer: share of the field's turning the gyro accounted for (None: no gyro)
    mounting: str = ""  # magnetometer with a gyro: its axes against the IMU's ("x->-y, y->x, z->z (90 deg about -z)"), ...
    mounting_misalignment_deg: float | None = None  # ... the small rotation left, degrees ...
    mounting_misalignment_sd_deg: float | None = None  # ... and its predicted sd (model/mounting.py)

    @property
    def name(self) -> str:
        """DiagnosticStatus name: ``margcal: <sensor>``."""
        return f"margcal: {self.sensor}"

    def values(self) -> list[tuple[str, str]]:
        """Key/value pairs (strings) for the DiagnosticStatus."""

        def num(x: float | None, fmt: str = "{:.6g}") -> str:
            return "" if x is None else fmt.format(x)

        out = [
            ("state", self.state.value),
            ("samples_seen", str(self.samples_seen)),
            ("samples_kept", str(self.samples_kept)),
            ("samples_rejected", str(self.samples_rejected)),
        ]
        out += [(f"dropped_{k}", str(v)) for k, v in sorted(self.dropped.items())]
        out += [
            ("buffer_size", str(self.buffer_size)),
            ("coverage", num(self.coverage, "{:.3f}")),
        ]
        out += [(f"indicator_{k}", num(v)) for k, v in self.indicators.items()]
        out += [
            ("predicted_error", num(self.predicted_error)),
            ("error_threshold", num(self.error_threshold)),
            ("residual", num(self.residual)),
            ("offset", "" if self.offset is None else " ".join(f"{x:.6g}" for x in self.offset)),
            ("matrix", "" if self.matrix is None else " ".join(f"{x:.6g}" for x in self.matrix)),
            ("norm", num(self.norm)),
            ("age", num(self.age, "{:.1f}")),
            ("fits_accepted", str(self.fits_accepted)),
            ("fits_rejected", str(self.fits_rejected)),
            ("last_rejection", self.last_rejection),
            ("changes_detected", str(self.changes_detected)),
            ("samples_passed", str(self.samples_passed)),
            ("time_base_resets", str(self.time_base_resets)),
            ("gyro_ignored", str(self.gyro_ignored)),
            ("partial", str(self.partial).lower()),
            ("updated_parameters", " ".join(self.updated_parameters)),
            ("prior_parameters", " ".join(self.prior_parameters)),
            ("heading_p95_level_deg", num(self.heading_p95_level_deg, "{:.3g}")),
            ("heading_p95_tilt30_deg", num(self.heading_p95_tilt30_deg, "{:.3g}")),
            ("heading_typical_level_deg", num(self.heading_typical_level_deg, "{:.3g}")),
            ("heading_typical_tilt30_deg", num(self.heading_typical_tilt30_deg, "{:.3g}")),
            ("heading_inclination_deg", num(self.heading_inclination_deg, "{:.3g}")),
            ("tilt_seen_deg", num(self.tilt_seen_deg, "{:.3g}")),
            ("gyro_explained", num(self.gyro_explained, "{:.4g}")),
            ("mounting", self.mounting),
            ("mounting_misalignment_deg", num(self.mounting_misalignment_deg, "{:.3g}")),
            ("mounting_misalignment_sd_deg", num(self.mounting_misalignment_sd_deg, "{:.3g}")),
        ]
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain types, for JSON (the replay timeline)."""
        return {
            "sensor": self.sensor, "level": int(self.level), "state": self.state.value, "message": self.message,
            "t": self.t, "samples_seen": self.samples_seen, "samples_kept": self.samples_kept,
            "samples_rejected": self.samples_rejected, "dropped": dict(self.dropped), "buffer_size": self.buffer_size,
            "coverage": self.coverage, "indicators": dict(self.indicators), "predicted_error": self.predicted_error,
            "error_threshold": self.error_threshold, "residual": self.residual,
            "offset": None if self.offset is None else list(self.offset),
            "matrix": None if self.matrix is None else list(self.matrix), "norm": self.norm, "age": self.age,
            "fits_accepted": self.fits_accepted, "fits_rejected": self.fits_rejected,
            "last_rejection": self.last_rejection, "changes_detected": self.changes_detected,
            "samples_passed": self.samples_passed, "time_base_resets": self.time_base_resets,
            "gyro_ignored": self.gyro_ignored, "partial": self.partial,
            "updated_parameters": list(self.updated_parameters), "prior_parameters": list(self.prior_parameters),
            "heading_p95_level_deg": self.heading_p95_level_deg, "heading_p95_tilt30_deg": self.heading_p95_tilt30_deg,
            "heading_typical_level_deg": self.heading_typical_level_deg,
            "heading_typical_tilt30_deg": self.heading_typical_tilt30_deg,
            "heading_inclination_deg": self.heading_inclination_deg,
            "tilt_seen_deg": self.tilt_seen_deg, "gyro_explained": self.gyro_explained, "mounting": self.mounting,
            "mounting_misalignment_deg": self.mounting_misalignment_deg,
            "mounting_misalignment_sd_deg": self.mounting_misalignment_sd_deg,
        }


def pct(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    v = 100.0 * x
    return f"{v:.1f} %" if abs(v) >= 1.0 else f"{v:.2g} %"
