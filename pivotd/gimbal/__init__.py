"""Gimbal side: kinematics (direction <-> pan/tilt), motion (Ruckig), serial link."""
