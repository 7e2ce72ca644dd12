"""The node's field model (issue 28): a position from the parameters or from a NavSatFix another node publishes.

Real rclpy (skipped where ROS 2 is absent, required under CI): the magnetometer's reference norm and heading
inclination become the WMM2025 field's, and ``/calib/status`` says which field in its ``field_model`` value.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from msgdata import import_rclpy

rclpy = import_rclpy()
pytest.importorskip("pygeomag")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import NavSatFix, NavSatStatus  # noqa: E402
from test_node import Harness, context  # noqa: E402, F401  (context: the fixture, a Context of each test's own)

from ros_margcal.model.geomag import field_at  # noqa: E402
from ros_margcal.ros.node import MargCalNode  # noqa: E402


class Gps(Harness):
    """The node under test and a peer node that publishes NavSatFix on gps/fix and records /calib/status
    (``spin_until`` and ``close`` are test_node's harness's)."""

    def __init__(self, context: Context, cal_file: Path, **params: Any) -> None:  # noqa: F811 (test_node's fixture)
        overrides = [Parameter("calibration_file", value=str(cal_file)), Parameter("status_period_s", value=0.1),
                     Parameter("accel.enabled", value=False)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = MargCalNode(context=context, parameter_overrides=overrides)
        self.peer = Node("margcal_gps_peer", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.status: list[Any] = []
        self.pub = self.peer.create_publisher(NavSatFix, "gps/fix", qos_profile_sensor_data)
        self.peer.create_subscription(DiagnosticArray, "/calib/status", self.status.append, 10)

    def fix(self, lat: float, lon: float, status: int = NavSatStatus.STATUS_FIX, alt: float = 520.0) -> None:
        """Publish one fix a few times (best effort) and let the node take it."""
        msg = NavSatFix(latitude=lat, longitude=lon, altitude=alt)
        msg.status.status = status
        assert self.spin_until(lambda: self.pub.get_subscription_count() > 0, 5.0), "the node does not subscribe gps/fix"
        for _ in range(3):
            self.pub.publish(msg)
            self.spin_until(lambda: False, 0.1)

    def field_model(self) -> str:
        """The ``field_model`` value of the latest magnetometer status."""
        self.status.clear()
        assert self.spin_until(lambda: bool(self.status), 3.0), "no /calib/status received"
        st = next(s for s in self.status[-1].status if s.name == "margcal: mag")
        return next(kv.value for kv in st.values if kv.key == "field_model")



@pytest.fixture
def gps(context: Context, tmp_path: Path) -> Iterator[Gps]:  # noqa: F811 (test_node's fixture)
    """A node without a position, fed from a peer's gps/fix."""
    g = Gps(context, tmp_path / "cal.yaml")
    try:
        yield g
    finally:
        g.close()


def test_position_parameters_set_the_norm_and_inclination(context: Context, tmp_path: Path) -> None:  # noqa: F811 (test_node's fixture)
    """latitude/longitude parameters: the WMM2025 field's norm and inclination, said in the status."""
    g = Gps(context, tmp_path / "cal.yaml", latitude=48.1, longitude=11.6, altitude=520.0)
    try:
        cfg, f = g.node.configs["mag"], field_at(48.1, 11.6, 520.0)
        assert cfg.reference_norm == pytest.approx(f.intensity_t, rel=1e-6)
        assert cfg.heading_inclination_deg == pytest.approx(f.inclination_deg, abs=1e-6)
        assert g.field_model().startswith("field from WMM2025 at 48.1°N 11.6°E: 48.")
    finally:
        g.close()


def test_a_bad_position_parameter_is_refused_and_the_node_runs(context: Context, tmp_path: Path) -> None:  # noqa: F811 (test_node's fixture)
    """latitude 95: an error log line, no field model, the node runs as without a position."""
    g = Gps(context, tmp_path / "cal.yaml", latitude=95.0, longitude=11.6)
    try:
        assert g.node.configs["mag"].reference_norm is None
        assert g.field_model().startswith("none: no position")
    finally:
        g.close()


def test_navsatfix_from_another_node(gps: Gps) -> None:
    """No fix: ignored; the first fix: used; 10 km on: kept; 100 km on: moved (the worker gets each new config)."""
    assert gps.field_model().startswith("none: no position")
    gps.fix(48.1, 11.6, status=NavSatStatus.STATUS_NO_FIX)
    assert gps.node.configs["mag"].reference_norm is None
    gps.fix(math.nan, 11.6)
    assert gps.node.configs["mag"].reference_norm is None
    gps.fix(48.1, 11.6)
    munich = field_at(48.1, 11.6, 520.0)
    assert gps.node.configs["mag"].reference_norm == pytest.approx(munich.intensity_t, rel=1e-6)
    assert gps.field_model().startswith("field from WMM2025 at 48.1°N 11.6°E")
    gps.fix(48.19, 11.6)  # 10 km north: the same field to 0.05 %
    assert gps.node.configs["mag"].latitude_deg == 48.1
    gps.fix(52.5, 13.4)  # Berlin
    berlin = field_at(52.5, 13.4, 520.0)
    assert gps.node.configs["mag"].reference_norm == pytest.approx(berlin.intensity_t, rel=1e-6)
    assert gps.field_model().startswith("field from WMM2025 at 52.5°N 13.4°E")
