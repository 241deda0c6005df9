"""pivotd: gimbal controller daemon implementing PIVOT viewing-direction optimization."""

__version__ = "0.1.0"
