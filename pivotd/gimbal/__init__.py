"""Gimbal side: the interface the daemon drives (interface), kinematics (direction <-> pan/tilt), motion (Ruckig),
and the host side of pivotd's serial protocol (link)."""
