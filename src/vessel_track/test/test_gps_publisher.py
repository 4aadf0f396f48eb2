"""NavSatFix content of the gps_publisher (needs sensor_msgs from the built workspace)."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("sensor_msgs.msg", reason="sensor_msgs is not importable: source ros2_ws/install/setup.bash")


def _track(**kw):
    from vessel_calib.node_support import sec_to_stamp

    base = dict(has_world=True, status=1, latitude=32.703, longitude=-117.233, last_seen=sec_to_stamp(100.0),
                position_covariance=[25.0, 5.0, 5.0, 4.0], expected_error_m=10.0, is_target=True)
    base.update(kw)
    return SimpleNamespace(**base)


def test_enu_covariance_modes():
    from vessel_track.error_model import MEAN_RADIAL_ERROR_PER_SIGMA
    from vessel_track.gps_publisher_node import enu_covariance

    sigma2 = (10.0 / MEAN_RADIAL_ERROR_PER_SIGMA) ** 2
    total = np.array(enu_covariance([25.0, 5.0, 5.0, 4.0], 10.0, "sum", 9.0)).reshape(3, 3)
    np.testing.assert_allclose(total[:2, :2], [[25 + sigma2, 5], [5, 4 + sigma2]])
    assert total[2, 2] == 9.0 and total[0, 2] == 0.0
    only_filter = np.array(enu_covariance([25.0, 5.0, 5.0, 4.0], 10.0, "filter")).reshape(3, 3)
    np.testing.assert_allclose(only_filter[:2, :2], [[25, 5], [5, 4]])
    model = np.array(enu_covariance([np.nan] * 4, 10.0, "sum")).reshape(3, 3)
    np.testing.assert_allclose(model[:2, :2], np.eye(2) * sigma2)
    biggest = np.array(enu_covariance([1.0, 0, 0, 1.0], 10.0, "max")).reshape(3, 3)
    np.testing.assert_allclose(biggest[:2, :2], np.eye(2) * sigma2)
    assert all(math.isnan(v) for v in enu_covariance([np.nan] * 4, math.nan, "sum")[:2])


def test_fix_status_follows_the_target():
    from sensor_msgs.msg import NavSatStatus

    from vessel_track.gps_publisher_node import fix_fields_of_track

    ok = fix_fields_of_track(_track(), 104.0, max_coast_s=12.0)
    assert ok.status == NavSatStatus.STATUS_FIX and ok.latitude == 32.703
    for bad in (None, _track(has_world=False), _track(status=3), _track(latitude=math.nan),
                _track(position_covariance=[math.nan] * 4, expected_error_m=math.nan)):
        fields = fix_fields_of_track(bad, 104.0, max_coast_s=12.0)
        assert fields.status == NavSatStatus.STATUS_NO_FIX and math.isnan(fields.latitude)
    stale = fix_fields_of_track(_track(), 130.0, max_coast_s=12.0)
    assert stale.status == NavSatStatus.STATUS_NO_FIX
