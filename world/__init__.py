"""The arena: workspace, obstacles, occupancy maps, S against obstacles (sweep), routes."""
