"""Offscreen rendering: 3D views of the scene, 2D map panels, episode videos and stills."""
