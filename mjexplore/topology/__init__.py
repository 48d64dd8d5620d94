"""From the occupancy grid to topology: frontiers, information gain, GVD and the TER."""
