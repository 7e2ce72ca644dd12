"""A ``CoverageView`` as an RViz ``visualization_msgs/MarkerArray`` (needed by the node alone: ROS messages).

Per sensor (marker namespace ``margcal/<sensor>``), in the sensor's ``frame_id`` and the view's display
coordinates (``stream/view.py``: one metre is one field radius about the centre):

- id 0, ``POINTS``: the buffered samples, coloured by state (collecting amber, ready blue, calibrated
  green, rejected red);
- id 1, ``CUBE_LIST``: the covered direction bins on the unit sphere, grey;
- id 2, ``SPHERE``: the fitted ellipsoid of the raw readings, translucent, once calibrated (deleted otherwise);
- id 3, ``TEXT_VIEW_FACING``: "<sensor>: <state>, <coverage> % of bins", above the sphere.

In RViz: add a MarkerArray display on ``/calib/markers`` and set the fixed frame to the sensor's frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..stream.view import CoverageView

__all__ = ["STATE_COLOURS", "coverage_markers", "rotation_quaternion"]

STATE_COLOURS = {"collecting": (1.0, 0.7, 0.0), "ready": (0.2, 0.5, 1.0), "calibrated": (0.1, 0.8, 0.2),
                 "rejected": (0.9, 0.1, 0.1)}
"""RGB per state of ``stream/status.State``."""
POINT_SIZE = 0.02
BIN_SIZE = 0.05
"""Marker sizes, display metres (one metre is one field radius)."""


def rotation_quaternion(r: Any) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation matrix ``r`` (3, 3), det +1 (Shepperd's method, the largest pivot)."""
    m = np.asarray(r, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    k = int(np.argmax([tr, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _marker(header: Any, ns: str, mid: int, kind: int, rgb: tuple[float, float, float], alpha: float) -> Marker:
    m = Marker(header=header, ns=ns, id=mid, type=kind, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=rgb[0], g=rgb[1], b=rgb[2], a=alpha)
    return m


def _points(xyz: Any) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in np.asarray(xyz, dtype=float)]


def coverage_markers(view: CoverageView, header: Any) -> MarkerArray:
    """The four markers of one sensor's view (see the module docstring); ``header`` gives frame and stamp."""
    ns = f"margcal/{view.sensor}"
    rgb = STATE_COLOURS.get(view.state, (0.7, 0.7, 0.7))
    samples = _marker(header, ns, 0, Marker.POINTS, rgb, 1.0)
    samples.scale = Vector3(x=POINT_SIZE, y=POINT_SIZE, z=0.0)
    samples.points = _points(view.points)
    bins = _marker(header, ns, 1, Marker.CUBE_LIST, (0.6, 0.6, 0.6), 0.6)
    bins.scale = Vector3(x=BIN_SIZE, y=BIN_SIZE, z=BIN_SIZE)
    bins.points = _points(view.bins)
    sphere = _marker(header, ns, 2, Marker.SPHERE, rgb, 0.25)
    if view.axes is None or view.radii is None:
        sphere.action = Marker.DELETE
    else:
        x, y, z, w = rotation_quaternion(view.axes)
        sphere.pose = Pose(orientation=Quaternion(x=x, y=y, z=z, w=w))
        sphere.scale = Vector3(x=2.0 * float(view.radii[0]), y=2.0 * float(view.radii[1]), z=2.0 * float(view.radii[2]))
    text = _marker(header, ns, 3, Marker.TEXT_VIEW_FACING, (1.0, 1.0, 1.0), 1.0)
    text.pose.position.z = 1.5
    text.scale.z = 0.12
    text.text = f"{view.sensor}: {view.state}, {100 * view.coverage:.0f} % of bins ({len(view.points)} samples)"
    return MarkerArray(markers=[samples, bins, sphere, text])
