"""Simulated visual localization: how often does the robot know where it is, per camera policy.

A camera (pinhole, level roll) rides on the gimbal of a robot that follows a route through a landmark
map with occluding walls. Each policy steers the gimbal through the daemon's jerk-limited control loop;
every frame the visible landmarks are projected with noise, detection losses and outlier matches, a
PnP + RANSAC estimator recovers the camera pose, and the error against ground truth is scored.

Modules: ``stack`` (the only place that imports the planner, control loop, motion model, maps and
config), ``camera``, ``scenes``, ``fisher``, ``policies``, ``simulate``, ``estimator``, ``metrics``.
"""
