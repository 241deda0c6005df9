"""pivotd configuration: the settings dataclasses (:mod:`.settings`) and the YAML reader (:mod:`.yaml_reader`)."""

from pivotd.config.settings import (
    Config,
    ControlConfig,
    GimbalConfig,
    LoggingConfig,
    MapConfig,
    MapFilters,
    MapLayers,
    MotionConfig,
    PivotConfig,
    PlannerConfig,
    SimConfig,
    ZenohConfig,
    endpoint_problem,
    load_config,
)

__all__ = [
    "Config",
    "ControlConfig",
    "GimbalConfig",
    "LoggingConfig",
    "MapConfig",
    "MapFilters",
    "MapLayers",
    "MotionConfig",
    "PivotConfig",
    "PlannerConfig",
    "SimConfig",
    "ZenohConfig",
    "endpoint_problem",
    "load_config",
]
