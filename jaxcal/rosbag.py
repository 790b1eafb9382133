"""The ROS bag reader's old import path: :mod:`jaxcal.formats.rosbag` re-exported."""

from __future__ import annotations

from jaxcal.formats.rosbag import IMU_TYPE, POSE_TYPES, TIME_SOURCES, bag_topics, read_rosbag

__all__ = ["IMU_TYPE", "POSE_TYPES", "TIME_SOURCES", "read_rosbag", "bag_topics"]
