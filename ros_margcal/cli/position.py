"""``--lat``, ``--lon``, ``--alt``, ``--date`` of ``calibrate`` and ``replay``: the field from the World Magnetic Model.

A position makes the magnetometer's reference norm the model's field intensity in the recording's unit and
the heading figures' inclination the model's (``PipelineConfig.at_position``, ``model/geomag.py``), as
ArduPilot and PX4 scale their fits to the WMM field at the GPS position.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
from typing import Any

import numpy as np

from ..model.calibration import Calibration
from ..model.errors import ConfigError
from ..model.geomag import decimal_year
from ..stream.config import FIELD_SPECS, PipelineConfig

__all__ = ["RADIUS_NOTE_REL", "add_position_args", "field_line", "position_options", "radius_note"]

RADIUS_NOTE_REL = 0.05
"""``radius_note`` speaks when the readings' radius and the model's intensity differ by more than this share."""


def add_position_args(p: argparse.ArgumentParser) -> None:
    """Add ``--lat``, ``--lon``, ``--alt``, ``--date`` to a subcommand."""
    p.add_argument("--lat", type=float, default=None, metavar="DEG",
                   help="geodetic latitude of the recording: the magnetometer's reference norm and the heading figures' "
                   "inclination from the World Magnetic Model (WMM2025; needs --lon)")
    p.add_argument("--lon", type=float, default=None, metavar="DEG", help="longitude, deg east (with --lat)")
    p.add_argument("--alt", type=float, default=0.0, metavar="M", help="altitude above the WGS 84 ellipsoid, m (default 0)")
    p.add_argument("--date", default=None, metavar="YYYY-MM-DD",
                   help="date the model field is taken at (default today; WMM2025 holds 2025-2029)")


def position_options(args: argparse.Namespace) -> dict[str, Any]:
    """The ``PipelineConfig`` options of ``--lat/--lon/--alt/--date`` ({} without a position); ConfigError when one
    of --lat and --lon is missing or a value is unusable."""
    if args.lat is None and args.lon is None:
        if args.date is not None or args.alt != 0.0:
            raise ConfigError("--alt and --date need a position: give --lat and --lon too")
        return {}
    if args.lat is None or args.lon is None:
        raise ConfigError(f"a position needs --lat and --lon, got --lat {args.lat} and --lon {args.lon}")
    if not (math.isfinite(args.lat) and -90.0 <= args.lat <= 90.0):  # in the user's words, before the config's
        raise ConfigError(f"--lat must be a latitude in [-90, 90] deg, got {args.lat}")
    if not (math.isfinite(args.lon) and -180.0 <= args.lon <= 360.0):
        raise ConfigError(f"--lon must be a longitude in [-180, 360] deg east, got {args.lon}")
    spec = FIELD_SPECS["altitude_m"]
    if not (math.isfinite(args.alt) and spec.lo <= args.alt <= spec.hi):  # the config's range, in the option's name
        raise ConfigError(f"--alt must be an altitude in [{spec.lo:g}, {spec.hi:g}] m, got {args.alt:g}")
    opts: dict[str, Any] = {"latitude_deg": args.lat, "longitude_deg": args.lon, "altitude_m": args.alt}
    if args.date is not None:
        try:
            day = dt.date.fromisoformat(args.date)
        except ValueError as exc:
            raise ConfigError(f"--date must be YYYY-MM-DD, got {args.date!r}") from exc
        opts["field_year"] = decimal_year(day)
    return opts


def field_line(cfg: PipelineConfig, norm_given: bool = False) -> str:
    """What the model gave, for the console: the field, and what it set ("" without a position)."""
    f = cfg.field_model()
    if f is None:
        return ""
    if cfg.sensor != "mag":
        return f"{f.describe()}: not used (the accelerometer's norm is gravity)"
    if norm_given:
        used = "the heading figures' inclination (the norm is given by hand)"
    elif cfg.reference_norm is None:
        used = f"the heading figures' inclination (no norm in {cfg.unit}: a unit without a known scale)"
    else:
        used = f"reference norm {cfg.reference_norm:.6g} {cfg.unit} and the heading figures' inclination"
    return f"{f.describe()}: {used}"


def radius_note(cal: Calibration, cfg: PipelineConfig) -> str:
    """A note when the readings' radius (``norm / |det W|^(1/3)``, the field the sensor saw in its own gain) is more
    than ``RADIUS_NOTE_REL`` off the model's intensity: a local field (indoors, steel) or a sensor gain error."""
    f = cfg.field_model()
    if f is None or cfg.sensor != "mag" or cfg.reference_norm is None:
        return ""
    radius = cal.norm / abs(float(np.linalg.det(cal.matrix))) ** (1.0 / 3.0)
    rel = radius / cfg.reference_norm - 1.0
    if not abs(rel) > RADIUS_NOTE_REL:
        return ""
    return (f"note: the readings' radius {radius:.4g} {cfg.unit} is {100 * abs(rel):.3g} % {'above' if rel > 0 else 'below'} "
            f"the model's {cfg.reference_norm:.4g} {cfg.unit}: a local field (indoors, near steel) or a gain error of the "
            "sensor; if the field here is not the model's, --norm with the local intensity fits a ring's vertical terms better")
