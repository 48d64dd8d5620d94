"""mjexplore: MuJoCo simulator and learning stack for lidar-based autonomous exploration."""

__version__ = "0.1.0"
