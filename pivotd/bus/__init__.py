"""Zenoh session and ROS 2 (rmw_zenoh) wire compatibility."""
