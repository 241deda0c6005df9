"""Landmark maps: file formats, spatial index, per-waypoint retained sets."""
