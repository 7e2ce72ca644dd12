"""The simulator: true sensors, coverage patterns, motion, and the registry of sensor effects.

``simulation`` generates recordings (v = W^-1 h + b + e with the effects of ``effects.EFFECTS``);
``patterns`` gives direction sets, ``motion`` orientation histories and offset events.
"""

from __future__ import annotations

from .effects import EFFECTS, Effect, check_effects, sensor_model
from .motion import HardIronJump, Motion, OffsetDrift, sample_times, smooth_motion, tumbling_motion
from .patterns import PATTERNS, directions, unit_vectors
from .simulation import GRAVITY, magnetometer_stream, random_sensor, simulate, tumbling

__all__ = [
    "EFFECTS", "GRAVITY", "PATTERNS", "Effect", "HardIronJump", "Motion", "OffsetDrift", "check_effects",
    "directions", "magnetometer_stream", "random_sensor", "sample_times", "sensor_model", "simulate",
    "smooth_motion", "tumbling", "tumbling_motion", "unit_vectors"
]
