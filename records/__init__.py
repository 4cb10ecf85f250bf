"""Records of a run: run.mcap (Foxglove schemas), trajectories.csv, the live view, replay."""
