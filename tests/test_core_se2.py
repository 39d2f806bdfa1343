"""The one heading quaternion every written file holds (ROS messages, Foxglove scenes, evo trajectories)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from aslam.core import se2
from aslam.data_formats.ros_msgs import yaw_of_quaternion


@given(st.floats(-50.0, 50.0))
def test_a_heading_survives_its_quaternion(yaw):
    w, x, y, z = se2.yaw_quaternion(yaw)
    assert (x, y) == (0.0, 0.0) and math.isclose(w * w + z * z, 1.0)
    back = yaw_of_quaternion(x, y, z, w)
    assert abs(se2.wrap_angle(back - yaw)) < 1e-9


def test_a_left_turn_is_a_positive_rotation_about_up():
    """REP 103: counter-clockwise seen from above, as evo, Foxglove and ROS read it."""
    w, _, _, z = se2.yaw_quaternion(math.pi / 2)
    assert math.isclose(w, math.sqrt(0.5)) and math.isclose(z, math.sqrt(0.5))
