"""Occupancy-grid mapping from lidar scans and map-quality metrics."""
