"""Robot definitions and parameter files (pydantic v2, TOML); no I/O beyond reading them."""

from cablesvc.config.robot import (
    Robot,
    RobotFileError,
    RobotGeometry,
    load_robot,
    robot_search_path,
)

__all__ = ["Robot", "RobotFileError", "RobotGeometry", "load_robot", "robot_search_path"]
